# ruff: noqa  (a scratch script kept to reproduce the numbers in docs/RESULTS.md, session 19; not product code)
"""Session 19 held-out evaluation of the suite family `moving_demand` (or any families): the
suite's own episodes (`run_family`: the twin seeds of suite run seed --seed), every method paired
on them; paired differences to `service`, Wilcoxon and Mann-Whitney U p.

    PYTHONPATH=. python docs/results/issue24/session19/move/held_out.py moving_demand --seed 2291 \
        --methods service,service-track,pl-marl,pl-marl-track,dead-reckoning,greedy,clairvoyant --tup 15,50 --episodes 30
"""
import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

torch.set_num_threads(1)
from scipy import stats

from plmarl_sitl.learning.eval.evaluate import needed_policies
from plmarl_sitl.learning.eval.suite import load_suite, run_family, twin_seeds
from plmarl_sitl.learning.nn.io import load_policy

ap = argparse.ArgumentParser()
ap.add_argument("families")
ap.add_argument("--seed", type=int, required=True)
ap.add_argument("--methods", required=True)
ap.add_argument("--tup", default="15,50")
ap.add_argument("--episodes", type=int, default=30)
ap.add_argument("--out", default=None)
a = ap.parse_args()
methods = a.methods.split(",")
tups = [int(x) for x in a.tup.split(",")]
loaded = {p: load_policy(Path("policies") / p) for p in needed_policies(methods)}
spec, fams = load_suite("missions/suite/suite.yaml")
out = {"seed": a.seed, "episodes": a.episodes, "methods": methods, "families": {}}
for name in a.families.split(","):
    fam = fams[name]
    t0 = time.time()
    runs = run_family(fam, loaded, methods, tups, a.episodes, a.seed)
    print(f"{name} seed {a.seed} twin seeds {twin_seeds(a.seed, a.episodes, fam)} wall {time.time() - t0:.0f}s", flush=True)
    fo = out["families"][name] = {}
    for tup in tups:
        base = runs[("service", tup)].coverage
        for m in methods:
            c = runs[(m, tup)].coverage
            d = c - base
            row = {"coverage": c.tolist(), "mean": float(c.mean()), "lambda2": float(runs[(m, tup)].lambda2.mean())}
            if m != "service":
                row.update(d_mean=float(d.mean()), wins=int((d > 0).sum()), losses=int((d < 0).sum()),
                           p_wilcoxon=float(stats.wilcoxon(c, base).pvalue) if np.any(d != 0) else 1.0,
                           p_mwu=float(stats.mannwhitneyu(c, base, alternative="two-sided").pvalue))
            fo[f"{m}@{tup}"] = row
            extra = "" if m == "service" else f"  d {row['d_mean']:+.4f} w/l {row['wins']}/{row['losses']} pW {row['p_wilcoxon']:.2g} pMWU {row['p_mwu']:.2g}"
            print(f"  T_up {tup} {m:15s} {row['mean']:.4f} l2 {row['lambda2']:.3f}{extra}", flush=True)
if a.out:
    Path(a.out).write_text(json.dumps(out))
