"""End to end for one method: engine fit -> MAPPO -> TorchScript export -> card.

Used by `plmarl train`. The predictor for pl-marl / gru is fitted first (unless a state
dict or a policy's predictor.pt is given), frozen, and shipped inside predictor.pt together
with the tracker.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import subprocess
import time
from collections.abc import Callable
from pathlib import Path

import torch

from plmarl_sitl.config import to_dict
from plmarl_sitl.learning.nn.belief import BeliefTracker
from plmarl_sitl.learning.nn.features import FeatureScales
from plmarl_sitl.learning.nn.io import export_policy
from plmarl_sitl.learning.nn.policy import DeployedPolicy
from plmarl_sitl.learning.nn.predictor import make_predictor
from plmarl_sitl.learning.train.mappo import METHOD_PREDICTOR, Args, train
from plmarl_sitl.learning.train.predictor import (
    PredictorArgs,
    dead_reckoning_tracker,
    pair_rows,
    position_errors,
    train_predictor,
)
from plmarl_sitl.learning.train.scenarios import ScenarioArgs, describe_distribution
from plmarl_sitl.machine import machine_info
from plmarl_sitl.mission import load_mission


def git_commit() -> str:
    try:
        sha = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--", "plmarl_sitl"], capture_output=True, text=True).stdout.strip()
        return sha + ("+dirty" if dirty else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def engine_iters(kind: str, iters: int | None) -> int:
    """Iterations of the engine fit: `iters`, or the default of the predictor kind."""
    return iters or (1500 if kind == "mlp" else 300)


def fit_predictor(kind: str, mission, seed: int, iters: int | None, out: Path, log: Callable[[str], None],  # noqa: ANN001
                  on_iter: Callable[[int], None] | None = None) -> tuple[str, dict]:
    from plmarl_sitl.learning.train.run_predictors import build_dataset

    vm = mission.vehicle_model()
    t0 = time.time()
    train_set = build_dataset(mission, seed)
    test_set = build_dataset(mission, seed + 1000, scale=0.25)
    gen = torch.Generator().manual_seed(seed)
    xs, os_ = zip(*(pair_rows(v, gen) for v in train_set.values()), strict=True)
    tracker = BeliefTracker(make_predictor(kind, mission.signalling.buffer_len, mission.timing.dt_s, vm.max_speed_mps, vm.max_accel_mps2))
    pargs = PredictorArgs(iters=engine_iters(kind, iters), rows=512 if kind == "mlp" else 256, seed=seed)
    curve = train_predictor(tracker, torch.cat(xs), torch.cat(os_), pargs, log=log, on_iter=on_iter)
    path = out / f"predictor_{kind}_state.pt"
    torch.save(tracker.predictor.state_dict(), path)
    (out / "predictor_curve.json").write_text(json.dumps(curve))
    wall = time.time() - t0
    errors = {c: position_errors(tracker, pair_rows(v, gen)[0]) for c, v in test_set.items()}
    dr = {c: position_errors(dead_reckoning_tracker(mission.signalling.buffer_len), pair_rows(v, gen)[0]) for c, v in test_set.items()}
    args = {k: (list(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(pargs).items()}
    return str(path), {"wall_s": wall, "iters": pargs.iters, "position_error_m": errors,
                       "dead_reckoning_position_error_m": dr, "test_episodes": {c: int(v.shape[0]) for c, v in test_set.items()},
                       "args": args}


EVAL_TUPS = (5, 15, 50)  # the T_up a trained policy's card is evaluated at


def run_training(
    method: str,
    mission_path: str,
    episodes: int,
    seed: int,
    out: Path,
    num_envs: int = 16,
    predictor_state: str | None = None,
    predictor_iters: int | None = None,
    eval_episodes: int = 100,
    threads: int = 1,
    on_iter: Callable[[int, dict], None] | None = None,
    log: Callable[[str], None] = print,
    args_overrides: dict | None = None,
    on_engine_iter: Callable[[int], None] | None = None,
    on_imitation_round: Callable[[int], None] | None = None,
    on_eval_decision: Callable[[int], None] | None = None,
) -> dict:
    torch.set_num_threads(threads)
    out.mkdir(parents=True, exist_ok=True)
    # Intermediate files (engine state, MAPPO checkpoint); `out` gets only what ships.
    work = Path("runs") / "work" / (out.resolve().as_posix().strip("/").replace("/", "_") + f"-seed{seed}")
    work.mkdir(parents=True, exist_ok=True)
    mission = load_mission(mission_path)
    card: dict = {"method": method, "mission": mission.name, "seed": seed, "git_commit": git_commit(), "training": {}}
    kind = METHOD_PREDICTOR[method]
    if kind in ("mlp", "gru") and predictor_state is None:
        log(f"fitting the {kind} inference engine ...")
        predictor_state, info = fit_predictor(kind, mission, seed, predictor_iters, work, log, on_engine_iter)
        card["training"]["predictor_wall_s"] = info["wall_s"]
        card["predictor"] = info
    args = Args(method=method, mission=mission_path, predictor_state=predictor_state, seed=seed, episodes=episodes,
                num_envs=num_envs, out=str(work / "mappo"), threads=threads, **(args_overrides or {}))
    res = train(args, progress=on_iter, on_imitation_round=on_imitation_round)
    if res.get("imitation"):
        card["training"]["imitation_wall_s"] = res["imitation"]["wall_s"]
        card["imitation"] = res["imitation"]
    # What a user must not fly it beyond without a word (the launcher and agent warn on another N).
    dist_n = dataclasses.asdict(ScenarioArgs()).get("n_uavs") if args.general else None
    card["trained_on"] = {"n_uavs": list(dist_n) if dist_n else [mission.n_uavs, mission.n_uavs],
                          "vehicle": to_dict(mission.vehicle_model())}
    card["training"]["distribution"] = describe_distribution(
        args.general, args.tup_choices,
        {"from_episode": args.failure_start_episode, "probability": args.failure_prob, "at_s": args.failure_at_s},
        ScenarioArgs.of(args))
    card["training"]["selection"] = {**res["selection"], "rule": "best mean coverage of the deterministic actor on a "
                                     "fixed validation set of training-distribution scenarios (training-range seeds)"}
    card["training"].update({"episodes": res["episodes"], "mappo_wall_s": res["wall_s"], "final": res["last"],
                             "machine": machine_info(), "torch_threads": threads})
    card["config"] = {k: (list(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(args).items()}
    # The engine this run fitted lives in a scratch folder under runs/work, which a reader of the
    # card cannot find: what ships is this folder's predictor.pt (card["predictor"] says how it was fitted).
    if "predictor" in card:
        card["config"]["predictor_state"] = "predictor.pt"
    card["training"]["total_wall_s"] = sum(card["training"].get(k, 0.0) for k in ("predictor_wall_s", "imitation_wall_s", "mappo_wall_s"))
    shutil.copy(res["curve"], out / "curve.jsonl")
    tracker = res["tracker"]
    for p in tracker.parameters():
        p.requires_grad_(False)
    policy = DeployedPolicy(res["actor"], *FeatureScales.from_mission(mission))
    export_policy(out, tracker, policy, card)
    if eval_episodes > 0:
        from plmarl_sitl.learning.eval.evaluate import evaluate_methods
        from plmarl_sitl.learning.nn.io import load_policy

        loaded = load_policy(out, mission)
        ev = evaluate_methods(mission, {method: loaded}, [method], list(EVAL_TUPS), eval_episodes, seed=10_000 + seed, on_decision=on_eval_decision)
        card["eval"] = {"episodes": eval_episodes, "seed": 10_000 + seed, "coverage": ev["results"]}
        export_policy(out, tracker, policy, card)  # rewrite the card with the numbers
    return card
