# ruff: noqa  (a scratch script kept to reproduce the numbers of session 20; not product code)
"""Session 20: suite families on the suite's own episodes (`run_family`, the twin seeds of suite run
seed --seed), the shipped methods and a trained policy directory, all paired on the same episodes:
coverage, lambda_2, paired difference / wins / losses / Wilcoxon signed-rank and unpaired two-sided
Mann-Whitney U against `service` and `service-track`.

    PYTHONPATH=. python docs/results/issue24/session20/learn/held_out.py moving_demand --seed 2391 \
        --methods service,service-track,pl-marl,pl-marl-track --policy policies/pl-marl-move --tup 15,50 --episodes 30

The policy in --policy flies as `move` (its plan point) and `move-track` (track_sensed_m 30), through
the same factories as `pl-marl` and `pl-marl-track`.
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
ap.add_argument("--policy", required=True)
ap.add_argument("--policy-methods", default="move,move-track")
ap.add_argument("--tup", default="15,50")
ap.add_argument("--episodes", type=int, default=30)
ap.add_argument("--out", default=None)
a = ap.parse_args()
methods = a.methods.split(",")
pmethods = a.policy_methods.split(",")
tups = [int(x) for x in a.tup.split(",")]
loaded = {p: load_policy(Path("policies") / p) for p in needed_policies(methods)}
mine = {"pl-marl": load_policy(Path(a.policy))}
alias = {"move": "pl-marl", "move-track": "pl-marl-track"}
spec, fams = load_suite("missions/suite/suite.yaml")
out = {"seed": a.seed, "episodes": a.episodes, "methods": methods + pmethods, "policy": a.policy, "families": {}}


def compare(c, base):
    d = c - base
    return dict(d_mean=float(d.mean()), wins=int((d > 0).sum()), losses=int((d < 0).sum()),
                p_wilcoxon=float(stats.wilcoxon(c, base).pvalue) if np.any(d != 0) else 1.0,
                p_mwu=float(stats.mannwhitneyu(c, base, alternative="two-sided").pvalue))


for name in a.families.split(","):
    fam = fams[name]
    t0 = time.time()
    runs = run_family(fam, loaded, methods, tups, a.episodes, a.seed)
    mr = run_family(fam, mine, [alias[m] for m in pmethods], tups, a.episodes, a.seed)
    for m in pmethods:
        for t in tups:
            if (alias[m], t) in mr:
                runs[(m, t)] = mr[(alias[m], t)]
    ftups = sorted({t for (_, t) in runs})
    print(f"{name} seed {a.seed} twin seeds {twin_seeds(a.seed, a.episodes, fam)} wall {time.time() - t0:.0f}s", flush=True)
    fo = out["families"][name] = {}
    for tup in ftups:
        base = runs[("service", tup)].coverage
        trk = runs[("service-track", tup)].coverage if ("service-track", tup) in runs else None
        for m in methods + pmethods:
            r = runs[(m, tup)]
            c = r.coverage
            row = {"coverage": c.tolist(), "lambda2_ep": r.lambda2.tolist(), "mean": float(c.mean()),
                   "lambda2": float(r.lambda2.mean())}
            line = f"  T_up {tup} {m:15s} {row['mean']:.4f} l2 {row['lambda2']:.3f}"
            if m != "service":
                row["vs_service"] = compare(c, base)
                v = row["vs_service"]
                line += f"  vs service {v['d_mean']:+.4f} w/l {v['wins']}/{v['losses']} pW {v['p_wilcoxon']:.2g} pMWU {v['p_mwu']:.2g}"
            if trk is not None and m not in ("service", "service-track"):
                row["vs_track"] = compare(c, trk)
                v = row["vs_track"]
                line += f" | vs track {v['d_mean']:+.4f} w/l {v['wins']}/{v['losses']} pW {v['p_wilcoxon']:.2g} pMWU {v['p_mwu']:.2g}"
            fo[f"{m}@{tup}"] = row
            print(line, flush=True)
if a.out:
    Path(a.out).write_text(json.dumps(out))
