# ruff: noqa  (a scratch probe kept to reproduce the numbers in docs/RESULTS.md, session 15; not product code)
"""Session 15 step 1, TRAINING twin seeds only: `service` against the same plan with the
search placement (model/placement.py) on the same common knowledge, paired, plus references.

    PYTHONPATH=. python docs/results/issue24/session15/probe_search.py 20 4242 2of6_a,2of6_b,paper 15 search,clairvoyant
"""
import sys, time
import numpy as np
import torch
torch.set_num_threads(1)
from scipy import stats
from plmarl_sitl.learning.eval.controllers import ServiceController
from plmarl_sitl.learning.eval.evaluate import controller_factory, run_method
from plmarl_sitl.mission import load_mission
from plmarl_sitl.model.placement import LearnedPlacement, SearchPlacement
from plmarl_sitl.learning.nn.placement import load_placement_scorer
from plmarl_sitl.model.service import ServiceGrid, plan_geometry


def with_placer(placer):
    def make(env):
        c = ServiceController(env.mission)
        c.targets.grid = ServiceGrid(*plan_geometry(env.mission), placer=placer)
        return c
    return make

fams = {"2of6_a": "missions/suite/failure_2of6_a.yaml", "2of6_b": "missions/suite/failure_2of6_b.yaml",
        "transit": "missions/suite/failure_transit.yaml", "split": "missions/suite/failure_split.yaml",
        "diffuse": "missions/suite/diffuse_failure.yaml", "paper": "missions/paper_urban.yaml",
        "n8": "missions/suite/n8.yaml", "n20r": "missions/suite/n20_random.yaml", "random": "missions/suite/random_layout.yaml"}
E = int(sys.argv[1]); seed = int(sys.argv[2]); which = sys.argv[3].split(","); tups = [int(x) for x in sys.argv[4].split(",")]
def learned(path, imp):
    return lambda env: with_placer(LearnedPlacement(load_placement_scorer(path), improve=imp))(env)
makers = {}
makers.update({"search": with_placer(SearchPlacement()), "search1": with_placer(SearchPlacement(firsts=1)),
          "learned": learned("policies/pl-marl/placement.pt", False),
          "learned+": learned("policies/pl-marl/placement.pt", True),
          "v1": learned("/tmp/w6/pl_a/placement.pt", False),
          "v1+": learned("/tmp/w6/pl_a/placement.pt", True),
          "v2": learned("/tmp/w6/pl_b/placement.pt", False),
          "v2+": learned("/tmp/w6/pl_b/placement.pt", True),
          "greedy": controller_factory("greedy", {}), "clairvoyant": controller_factory("clairvoyant", {})})
for f in which:
    fp = 1.0 if f == "diffuse" else 0.0
    for tup in tups:
        m = load_mission(fams[f]).with_tup(tup)
        t0 = time.time()
        base = run_method(m, lambda env: ServiceController(env.mission), E, seed, batch=E, failure_prob=fp).coverage
        line = f"{f} T{tup} service {base.mean():.4f} ({time.time()-t0:.0f}s) |"
        for name in sys.argv[5].split(","):
            t0 = time.time()
            c = run_method(m, makers[name], E, seed, batch=E, failure_prob=fp).coverage
            d = c - base
            p = stats.wilcoxon(c, base).pvalue if np.any(d != 0) else 1.0
            line += f" {name} {c.mean():.4f} d{d.mean():+.4f} w{int((d>0).sum())}/l{int((d<0).sum())} pw{p:.1g} pm{stats.mannwhitneyu(c, base).pvalue:.2g} ({time.time()-t0:.0f}s) |"
        print(line, flush=True)
