# ruff: noqa  (the session-15 evaluation harness kept to reproduce docs/RESULTS.md; not product code)
"""Held-out evaluation of issue 24.3 on the suite's episodes (`plmarl suite`'s own run_family,
twin seeds derived from --seed), per-episode coverage saved so methods run apart can be paired:

    PYTHONPATH=. python docs/results/issue24/session15/eval_place.py SEED METHODS FAMILIES TUPS EPISODES OUT.json

p: two-sided Mann-Whitney U (what `plmarl suite` reports) and the paired Wilcoxon signed-rank.
"""
import json, sys, time
from pathlib import Path
import numpy as np
import torch
torch.set_num_threads(1)
from plmarl_sitl.config import PROJECT_POLICIES
from plmarl_sitl.learning.eval.evaluate import needed_policies
from plmarl_sitl.learning.eval.suite import load_suite, run_family, select, family_tups
from plmarl_sitl.learning.nn.io import load_policy

seed, methods, fams, tups, E, out = int(sys.argv[1]), sys.argv[2].split(","), sys.argv[3], [int(t) for t in sys.argv[4].split(",")], int(sys.argv[5]), Path(sys.argv[6])
spec, families = load_suite(Path("missions/suite/suite.yaml"))
names = [n for n in fams.split(",") if n in families] if fams != "all" else select(spec, fams)  # the order given
doc = json.loads(out.read_text()) if out.exists() else {}
for name in names:
    fam = families[name]
    loaded = {p: load_policy(PROJECT_POLICIES / p, fam.missions[0]) for p in needed_policies(methods)}
    for method in methods:
        key = f"{name}|{method}"
        if key in doc:
            continue
        t0 = time.time()
        runs = run_family(fam, loaded, [method], tups, E, seed)
        doc[key] = {str(t): runs[(method, t)].coverage.tolist() for t in family_tups(fam, tups)}
        out.write_text(json.dumps(doc))
        print(f"{name} {method} " + " ".join(f"T{t} {np.mean(v):.4f}" for t, v in doc[key].items()) + f" ({time.time()-t0:.0f}s)", flush=True)
