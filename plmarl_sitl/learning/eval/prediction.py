"""Prediction error of the shipped inference engines vs dead reckoning, at given P-AoI.

    python -m plmarl_sitl.learning.eval.prediction missions/paper_urban.yaml --episodes 64 --seed 5

Trajectories: (1) the trained PL-MARL policy flying the mission (deterministic, its own
tracker, T_up = 15 s), the distribution a deployed agent's neighbours actually follow;
(2) the mixed controllers the engine was trained on (the greedy reference, heuristic, random waypoints,
OU accelerations), fresh seeds. Every tracker sees the same updates (T_up = 60 s, random
phase per neighbour, see `plmarl_sitl.learning.train.predictor.position_errors`).
"""

from __future__ import annotations

import argparse
import json

import torch

from plmarl_sitl.config import PROJECT_POLICIES
from plmarl_sitl.learning.eval.controllers import LearnedController
from plmarl_sitl.learning.nn.io import load_policy
from plmarl_sitl.learning.train.predictor import dead_reckoning_tracker, pair_rows, position_errors
from plmarl_sitl.learning.train.trajectories import CONTROLLERS, mixed_mobility, record
from plmarl_sitl.mission import load_mission


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("mission")
    ap.add_argument("--episodes", type=int, default=64)
    ap.add_argument("--seed", type=int, default=5)
    ap.add_argument("--policies", default=str(PROJECT_POLICIES))
    ap.add_argument("--ages", default="10,25,50")
    a = ap.parse_args(argv)
    torch.set_num_threads(1)
    mission = load_mission(a.mission)
    ages = tuple(int(x) for x in a.ages.split(","))
    engines = {"dead-reckoning": dead_reckoning_tracker(mission.signalling.buffer_len)}
    for m in ("pl-marl", "gru"):
        try:
            engines[m] = load_policy(f"{a.policies}/{m}", mission).tracker
        except Exception as exc:  # noqa: BLE001 - report and continue with what exists
            print(f"skipping {m}: {exc}")
    pl = load_policy(f"{a.policies}/pl-marl", mission)
    ctl = LearnedController(pl.tracker, pl.policy, mission)
    ctl.reset()
    sets = {"pl-marl policy": record(mission.with_tup(15), "policy", a.episodes, a.seed, policy=ctl.act)[0]}
    for k, c in enumerate(CONTROLLERS):
        sets[c] = record(mixed_mobility(mission), c, max(8, a.episodes // 4), a.seed + 100 + k)[0]
    gen = torch.Generator().manual_seed(a.seed)
    out: dict = {"ages_s": list(ages), "episodes": a.episodes, "seed": a.seed, "errors_m": {}}
    for name, traj in sets.items():
        rows = pair_rows(traj, gen)[0]
        out["errors_m"][name] = {e: position_errors(t, rows, ages) for e, t in engines.items()}
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
