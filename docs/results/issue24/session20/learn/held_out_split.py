# ruff: noqa  (a scratch script kept to reproduce the numbers in docs/RESULTS.md, session 19; not product code)
"""Session 20 (copied from session 19, with --policy): the share of steady-state seconds (t > 50 s) with lambda_2 = 0 (the live swarm split)
on the suite's own episodes of a family (the twin seeds of suite run seed --seed), per method.

    PYTHONPATH=. python docs/results/issue24/session20/learn/held_out_split.py moving_demand --seed 2391 --methods service,service-track,move,move-track
"""
import argparse
from pathlib import Path

import numpy as np
import torch

torch.set_num_threads(1)
from plmarl_sitl.learning.eval.evaluate import controller_factory
from plmarl_sitl.learning.eval.suite import BATCH, episodes_per_mission, load_suite, twin_seeds
from plmarl_sitl.twin.rollout import rollout
from plmarl_sitl.learning.nn.io import load_policy

ap = argparse.ArgumentParser()
ap.add_argument("family")
ap.add_argument("--seed", type=int, required=True)
ap.add_argument("--methods", required=True)
ap.add_argument("--tup", type=int, default=15)
ap.add_argument("--episodes", type=int, default=30)
ap.add_argument("--policy", default="policies/pl-marl-move")
a = ap.parse_args()
_, fams = load_suite("missions/suite/suite.yaml")
fam = fams[a.family]
seeds = twin_seeds(a.seed, a.episodes, fam)
counts = episodes_per_mission(a.episodes, len(fam.missions))
for meth in a.methods.split(","):
    make = controller_factory(meth.replace("move", "pl-marl"), {"pl-marl": load_policy(Path(a.policy if meth.startswith("move") else "policies/pl-marl"))})
    per = []
    for m, e, s in zip(fam.missions, counts, seeds, strict=True):
        if e == 0:
            continue
        runs = rollout(m.with_tup(a.tup), make, e, s[0], batch=BATCH)
        l2 = torch.cat([r.lambda2[:, 50:] for r in runs])
        cov = torch.cat([r.coverage[:, 50:] for r in runs])
        per.append((m.name, float((l2 <= 1e-6).double().mean()), float(l2.mean()), float(cov.mean())))
    allsplit = np.average([p[1] for p in per], weights=[c for c in counts if c > 0])
    print(f"seed {a.seed} T_up {a.tup} {meth:14s} split {allsplit:.3f} | " + " | ".join(f"{n.removeprefix('suite_moving_')} split {sp:.3f} l2 {l:.2f} cov {c:.4f}" for n, sp, l, c in per), flush=True)
