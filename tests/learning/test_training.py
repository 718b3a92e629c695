"""Few-episode training smoke runs: the MAPPO loop and the predictor fit actually learn something."""

from __future__ import annotations

import json
from pathlib import Path

import torch

from plmarl_sitl.nn import BeliefTracker, make_predictor
from plmarl_sitl.train.mappo import Args, train
from plmarl_sitl.train.predictor import PredictorArgs, dead_reckoning_tracker, position_errors, train_predictor

ROOT = Path(__file__).resolve().parents[2]


def test_mappo_smoke(tmp_path: Path) -> None:
    args = Args(
        method="tag-mappo", mission=str(ROOT / "missions" / "paper_urban.yaml"), episodes=4, num_envs=2,
        failure_start_episode=2, failure_prob=1.0, out=str(tmp_path), seed=3,
        imitation_rounds=1, imitation_episodes_per_round=2, critic_warmup_iters=1,
    )
    torch.manual_seed(0)
    res = train(args)
    rows = [json.loads(x) for x in (tmp_path / "curve.jsonl").read_text().splitlines()]
    assert [r["episodes"] for r in rows] == [2, 4]
    for key in ("charts/coverage", "charts/episodic_return", "losses/value_loss", "losses/policy_loss", "losses/entropy"):
        assert all(key in r and r[key] == r[key] for r in rows), key  # present and not NaN
    assert rows[0]["charts/failure_prob"] == 0.0 and rows[1]["charts/failure_prob"] == 1.0
    ck = torch.load(tmp_path / "checkpoint.pt", weights_only=False)
    fresh = res["actor"].__class__()
    moved = any(not torch.equal(ck["actor"][k], v) for k, v in fresh.state_dict().items() if k in ck["actor"])
    assert moved and ck["episodes"] == 4
    assert res["imitation"]["episodes"] == 2 and res["imitation"]["final_mse"] == res["imitation"]["final_mse"]


def test_predictor_fit_beats_dead_reckoning_on_braking_targets() -> None:
    """Targets that brake (v <- 0.85 v each second): phi must learn what CV cannot."""
    gen = torch.Generator().manual_seed(0)
    r, t_len = 96, 40
    v0 = torch.randn(r, 3, generator=gen) * torch.tensor([8.0, 8.0, 1.0])
    p = torch.rand(r, 3, generator=gen) * torch.tensor([800.0, 800.0, -100.0])
    states = []
    v = v0.clone()
    for _ in range(t_len):
        states.append(torch.cat([p, v], -1))
        p_next = p + 0.5 * (v + 0.85 * v)
        v, p = 0.85 * v, p_next
    traj = torch.stack(states, 1)
    torch.manual_seed(0)
    tr = BeliefTracker(make_predictor("mlp"), 10, 1.0)
    train_predictor(tr, traj, traj * 0, PredictorArgs(iters=60, rows=64, window=30, lr=1e-2, tup_choices=(15, 20)), log=lambda s: None)
    learnt = position_errors(tr, traj, ages=(10,), tup=30)[10]
    cv = position_errors(dead_reckoning_tracker(), traj, ages=(10,), tup=30)[10]
    assert learnt < 0.5 * cv, (learnt, cv)
