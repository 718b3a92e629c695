"""Few-episode training smoke runs: the MAPPO loop and the predictor fit actually learn something."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from plmarl_sitl.learning.nn import BeliefTracker, make_predictor
from plmarl_sitl.learning.train.mappo import Args, train
from plmarl_sitl.learning.train.predictor import PredictorArgs, dead_reckoning_tracker, position_errors, train_predictor

ROOT = Path(__file__).resolve().parents[2]


def test_mappo_smoke(tmp_path: Path) -> None:
    args = Args(
        method="tag-mappo", mission=str(ROOT / "missions" / "paper_urban.yaml"), episodes=4, num_envs=2,
        failure_start_episode=2, failure_prob=1.0, out=str(tmp_path), seed=3,
        imitation_rounds=1, imitation_episodes_per_round=2, imitation_tup_chunks=1, critic_warmup_iters=1,
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


def test_imitation_tup_chunks_cover_the_choices() -> None:
    """tup_chunks > 1: each round is split into batches whose T_up walk through a shuffled
    cycle of the choices, so no T_up range is left out of the warm start."""
    from plmarl_sitl.learning.nn import Actor
    from plmarl_sitl.learning.train.imitation import ImitationArgs, imitate_oracle
    from plmarl_sitl.mission import load_mission

    mission = load_mission(ROOT / "missions" / "paper_urban.yaml")
    torch.manual_seed(0)
    tracker = BeliefTracker(make_predictor("hold"), 10, 1.0)
    args = ImitationArgs(rounds=2, episodes_per_round=3, epochs=1, tup_choices=(5, 10, 50), tup_chunks=3, seed=1)
    rounds: list[int] = []  # what the imitation progress bar is fed (issue 26)
    res = imitate_oracle(Actor(), tracker, mission, args, log=lambda s: None, on_round=rounds.append)
    assert res["episodes"] == 6 and sorted(res["tups"][:3]) == [5, 10, 50] and sorted(res["tups"][3:]) == [5, 10, 50]
    assert rounds == [1, 2]


@pytest.mark.parametrize("method", ["pl-marl", "gru", "tag-mappo"])
def test_every_method_exports_a_policy_that_takes_the_team_plan(tmp_path: Path, monkeypatch, method: str) -> None:
    """The three learnt methods share one actor and differ only in the tracker, so each
    exported policy.pt takes the team-plan target, and the target moves its action."""
    from plmarl_sitl.learning.nn.io import load_policy
    from plmarl_sitl.learning.pipeline import run_training
    from plmarl_sitl.learning.train.mappo import METHOD_PREDICTOR

    monkeypatch.chdir(tmp_path)  # run_training keeps its intermediate files under ./runs
    state = None
    if METHOD_PREDICTOR[method] in ("mlp", "gru"):
        state = str(tmp_path / "predictor.pt")
        torch.save(make_predictor(METHOD_PREDICTOR[method]).state_dict(), state)
    run_training(method, str(ROOT / "missions" / "paper_urban.yaml"), episodes=2, seed=3, out=tmp_path / "out",
                 num_envs=2, predictor_state=state, eval_episodes=0, log=lambda _: None,
                 args_overrides={"imitation_rounds": 0, "validate_every": 0, "critic_warmup_iters": 0})
    lp = load_policy(tmp_path / "out")
    assert lp.takes_plan and lp.card["io"]["takes_plan"] and lp.card["method"] == method
    assert lp.card["io"]["reads_map"] is False and lp.card["config"]["reads_map"] is False  # the default: map-blind
    with torch.no_grad():
        belief, _, _, _ = lp.tracker(0.0, torch.zeros(2, 6), torch.zeros(2), *lp.tracker.init_state(torch.zeros(2, 6)))
        args = (torch.tensor([500.0, 500.0, -100.0, 0.0, 0.0, 0.0]), belief, torch.ones(2, dtype=torch.bool),
                torch.zeros(4), torch.tensor(False), torch.tensor([[450.0, 450.0, 60.0]]))
        assert not torch.equal(lp.policy(*args, torch.tensor([900.0, 500.0])), lp.policy(*args, torch.tensor([100.0, 500.0])))


def test_a_shipped_predictor_is_reused_as_it_is(tmp_path: Path, monkeypatch) -> None:
    """Issue 26: `--predictor policies/pl-marl/predictor.pt` trains (it was a raw traceback);
    the exported tracker answers exactly as the shipped one, and the card records the swarm
    sizes and vehicle it was trained on."""
    from plmarl_sitl.learning.nn.io import load_policy
    from plmarl_sitl.learning.pipeline import run_training

    monkeypatch.chdir(tmp_path)
    shipped = ROOT / "policies" / "pl-marl"
    run_training("pl-marl", str(ROOT / "missions" / "paper_urban.yaml"), episodes=2, seed=3, out=tmp_path / "out",
                 num_envs=2, predictor_state=str(shipped / "predictor.pt"), eval_episodes=0, log=lambda _: None,
                 args_overrides={"imitation_rounds": 0, "validate_every": 0, "critic_warmup_iters": 0, "general": False})
    new, old = load_policy(tmp_path / "out"), load_policy(shipped)
    held = torch.tensor([[0.0, 0.0, -60.0, 3.0, 1.0, 0.0], [50.0, 10.0, -60.0, -2.0, 0.0, 0.0]])
    with torch.no_grad():
        a = new.tracker(7.0, held, torch.tensor([0.0, 5.0]), *new.tracker.init_state(held))[0]
        b = old.tracker(7.0, held, torch.tensor([0.0, 5.0]), *old.tracker.init_state(held))[0]
    assert torch.equal(a, b)
    assert new.card["trained_on"]["n_uavs"] == [4, 4] and new.card["trained_on"]["vehicle"]["max_speed_mps"] == 20.0
    assert Path(new.card["config"]["predictor_state"]).is_file()  # the file the user gave, not a scratch path


def test_train_never_writes_over_a_policy_without_force(tmp_path: Path, monkeypatch, capsys) -> None:
    from plmarl_sitl.cli import main

    monkeypatch.chdir(tmp_path)
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "card.yaml").write_text("method: x\n")
    assert main(["train", "--out", "mine", "--episodes", "1"]) == 2
    assert "would write over a trained policy" in capsys.readouterr().err
    assert main(["train", "--out", str(ROOT / "policies" / "pl-marl"), "--episodes", "1"]) == 2
    assert "would write over the project's shipped policies" in capsys.readouterr().err
    assert (tmp_path / "mine" / "card.yaml").read_text() == "method: x\n"
