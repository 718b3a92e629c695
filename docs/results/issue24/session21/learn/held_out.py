# ruff: noqa  (a scratch script kept to reproduce the numbers of session 21; not product code)
"""Session 21: suite families on the suite's own episodes (the twin seeds of suite run seed --seed, as
`plmarl suite` draws them: `twin_seeds`, `episodes_per_mission`, `family_tups`, BATCH, the family's
failure probability), `service`, the current default `pl-marl`, candidate policy directories and
optionally the references, all paired on the same episodes. Per method and T_up: coverage (mean C(t),
t > 50 s), lambda_2, the split share (seconds with lambda_2 = 0, t > 50 s), the difference to `service`
and to the default with wins/losses, the suite's paired Wilcoxon p and unpaired MWU p
(learning/eval/stats.py::compare), and the per-episode fraction of the best reference run
(the best of service, greedy, clairvoyant among the methods given).

    PYTHONPATH=. python docs/results/issue24/session21/learn/held_out.py all --seed 2491 \
        --methods service,pl-marl --cand t25s23=runs/l21/t25-s23 --tup 15,50 --episodes 30 --out X.json
"""
import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

torch.set_num_threads(1)

from plmarl_sitl.learning.eval.evaluate import controller_factory, needed_policies
from plmarl_sitl.learning.eval.methods import GLOBAL_KNOWLEDGE
from plmarl_sitl.learning.eval.stats import compare
from plmarl_sitl.learning.eval.suite import BATCH, episodes_per_mission, family_tups, load_suite, twin_seeds
from plmarl_sitl.learning.nn.io import load_policy
from plmarl_sitl.twin.rollout import rollout

REFS = ("service", "greedy", "clairvoyant")

ap = argparse.ArgumentParser()
ap.add_argument("families")
ap.add_argument("--seed", type=int, required=True)
ap.add_argument("--methods", default="service,pl-marl")
ap.add_argument("--cand", action="append", default=[], help="NAME=DIR, flown as pl-marl is")
ap.add_argument("--tup", default="15,50")
ap.add_argument("--episodes", type=int, default=30)
ap.add_argument("--out", default=None)
a = ap.parse_args()
methods = a.methods.split(",")
tups = [int(x) for x in a.tup.split(",")]
loaded = {p: load_policy(Path("policies") / p) for p in needed_policies(methods)}
cands = dict(c.split("=", 1) for c in a.cand)
cand_loaded = {n: {"pl-marl": load_policy(Path(d))} for n, d in cands.items()}
spec, fams = load_suite("missions/suite/suite.yaml")
names = list(fams) if a.families == "all" else a.families.split(",")
out = {"seed": a.seed, "episodes": a.episodes, "methods": methods + list(cands), "cands": cands, "families": {}}


def make(meth):
    if meth in cands:
        return controller_factory("pl-marl", cand_loaded[meth])
    return controller_factory(meth, loaded)


def run(fam, meth, tup):
    seeds = twin_seeds(a.seed, a.episodes, fam)
    counts = episodes_per_mission(a.episodes, len(fam.missions))
    cov, l2, split = [], [], []
    for m, e, s in zip(fam.missions, counts, seeds, strict=True):
        if e == 0:
            continue
        for r in rollout(m.with_tup(tup), make(meth), e, s[0], batch=BATCH, failure_prob=fam.spec.failure_prob):
            cov.append(r.coverage[:, 50:].mean(-1).numpy())
            l2.append(r.lambda2[:, 50:].mean(-1).numpy())
            split.append((r.lambda2[:, 50:] <= 1e-6).double().mean(-1).numpy())
    return np.concatenate(cov), np.concatenate(l2), np.concatenate(split)


allm = methods + list(cands)
for name in names:
    fam = fams[name]
    t0 = time.time()
    ftups = family_tups(fam, tups)
    res = {}
    for meth in allm:
        if meth in GLOBAL_KNOWLEDGE:
            once = run(fam, meth, ftups[0])
            res.update({(meth, t): once for t in ftups})
    for t in ftups:
        for meth in allm:
            if meth not in GLOBAL_KNOWLEDGE:
                res[(meth, t)] = run(fam, meth, t)
    print(f"{name} seed {a.seed} wall {time.time() - t0:.0f}s", flush=True)
    fo = out["families"][name] = {}
    for t in ftups:
        refs = [m for m in REFS if (m, t) in res]
        best = np.max(np.stack([res[(m, t)][0] for m in refs]), 0)
        for meth in allm:
            c, l2, sp = res[(meth, t)]
            row = {"coverage": c.tolist(), "lambda2_ep": l2.tolist(), "split_ep": sp.tolist(), "mean": float(c.mean()),
                   "lambda2": float(l2.mean()), "split": float(sp.mean()), "frac_best": float((c / best).mean()),
                   "refs": refs}
            line = f"  {name:16s} T_up {t:2d} {meth:12s} {row['mean']:.4f} l2 {row['lambda2']:.2f} split {row['split']:.3f} frac {row['frac_best']:.3f}"
            for base in ("service", "pl-marl"):
                if meth != base and (base, t) in res and meth not in GLOBAL_KNOWLEDGE:
                    b = res[(base, t)][0]
                    v = compare(c, b)
                    v["d_mean"] = float((c - b).mean())
                    row[f"vs_{base}"] = v
                    line += f" | vs {base} {v['d_mean']:+.4f} {v['wins']}/{v['losses']} pW {v['p_paired']:.2g} pMWU {v['p']:.2g}"
            fo[f"{meth}@{t}"] = row
            print(line, flush=True)
    if a.out:
        Path(a.out).write_text(json.dumps(out))
