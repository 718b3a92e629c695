"""The references side by side: per-episode coverage differences on suite families, and the
cost of a decision of each (docs/RESULTS.md, "Honest references (issue 24)").

    python -m plmarl_sitl.bench.references --families paper,random,n8,failure --episodes 10 --seed 41 --tup 15

1. For each family, the suite's own episodes (`suite.twin_seeds`, the same batches as
   `plmarl suite`) under `greedy`, `clairvoyant` and `service`: per episode the steady-state
   coverage differences (how often and by how much the clairvoyant beats the others).
2. For each mission of --cost-missions, one batch of --cost-batch episodes per reference: the
   thread CPU time and wall time of `act()` per decision, over a whole episode.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
import torch

from plmarl_sitl.config import PAPER_MISSION, PROJECT_MISSIONS, PROJECT_SUITE
from plmarl_sitl.errors import run_reporting
from plmarl_sitl.learning.eval.evaluate import controller_factory
from plmarl_sitl.learning.eval.suite import BATCH, episodes_per_mission, family_tups, load_suite, select, twin_seeds
from plmarl_sitl.machine import machine_info
from plmarl_sitl.mission import load_mission
from plmarl_sitl.twin.env import CoverageEnv
from plmarl_sitl.twin.rollout import rollout

PROG = "python -m plmarl_sitl.bench.references"
REFS = ("greedy", "clairvoyant", "service")
FROM_S = 50


def differences(families: str, episodes: int, seed: int, tup: int) -> dict:
    spec, fams = load_suite(PROJECT_SUITE)
    out = {}
    for name in select(spec, families):
        fam = fams[name]
        t = family_tups(fam, [tup])[0]
        cov = {}
        for meth in REFS:
            parts = []
            for m, e, s in zip(fam.missions, episodes_per_mission(episodes, len(fam.missions)), twin_seeds(seed, episodes, fam),
                               strict=True):
                if e:
                    runs = rollout(m.with_tup(t), controller_factory(meth, {}), e, s[0], batch=BATCH,
                                   failure_prob=fam.spec.failure_prob)
                    parts += [r.coverage[:, FROM_S:].mean(-1).numpy() for r in runs]
            cov[meth] = np.concatenate(parts)
        row = {"coverage_mean": {k: float(v.mean()) for k, v in cov.items()}}
        for a, b in (("clairvoyant", "greedy"), ("clairvoyant", "service"), ("service", "greedy")):
            d = cov[a] - cov[b]
            row[f"{a}-{b}"] = {"wins": int((d > 0).sum()), "episodes": int(d.size), "mean": float(d.mean()),
                               "min": float(d.min()), "max": float(d.max())}
        out[name] = row
    return out


def decision_cost(mission_path: str, batch: int, seed: int) -> list[dict]:
    mission = load_mission(mission_path)
    rows = []
    for meth in REFS:
        env = CoverageEnv(mission, batch, seed)
        ctl = controller_factory(meth, {})(env)
        ctl.reset()
        obs = env.observe()
        cpu, wall = [], []
        with torch.inference_mode():
            while not env.done:
                w0, c0 = time.perf_counter(), time.thread_time()
                a = ctl.act(obs)
                cpu.append(time.thread_time() - c0)
                wall.append(time.perf_counter() - w0)
                obs, _, _ = env.step(a)
        rows.append({"mission": mission.name, "n_uavs": mission.n_uavs, "method": meth, "batch": batch,
                     "decisions": len(cpu), "cpu_ms_per_batch_decision": 1000 * float(np.mean(cpu)),
                     "wall_ms_per_batch_decision": 1000 * float(np.mean(wall))})
    return rows


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--families", default="paper,random,n8,failure", help="suite families ('' for none)")
    p.add_argument("--episodes", type=int, default=10)
    p.add_argument("--seed", type=int, default=41, help="suite run seed (picks the evaluation seeds, as plmarl suite)")
    p.add_argument("--tup", type=int, default=15, help="T_up for families that do not pin their own")
    p.add_argument("--cost-missions", default=f"{PAPER_MISSION},{PROJECT_MISSIONS / 'suite' / 'n8.yaml'},"
                   f"{PROJECT_MISSIONS / 'suite' / 'n20.yaml'}", help="missions whose decision cost to time ('' for none)")
    p.add_argument("--cost-batch", type=int, default=10, help="episodes per batch in the cost runs")
    args = p.parse_args(argv)

    def measure() -> int:
        torch.set_num_threads(1)
        res = {"command": "python -m plmarl_sitl.bench.references " + " ".join(sys.argv[1:]), "seed": args.seed,
               "machine": machine_info(), "torch_threads": 1,
               "differences": differences(args.families, args.episodes, args.seed, args.tup) if args.families else {},
               "cost": [r for m in args.cost_missions.split(",") if m for r in decision_cost(m, args.cost_batch, 1_000_000_001)]}
        print(json.dumps(res))
        return 0

    return run_reporting(PROG, measure)


if __name__ == "__main__":
    raise SystemExit(main())
