"""Which part of the dead-reckoning ablation costs the react student on failure_transit: the
constant-velocity tracker (beliefs, f) or the constant-velocity re-plan positions? Runs the
student with each of the four combinations on the suite's episodes (same twin seeds as
`plmarl suite failure_transit --seed S`).

    PYTHONPATH=. python docs/results/issue24/session13/dr_split.py policies/react/pl-marl --tup 50 --episodes 20 --seed 2413
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import torch

from plmarl_sitl.config import PROJECT_SUITE
from plmarl_sitl.learning.eval.controllers import LearnedController
from plmarl_sitl.learning.eval.evaluate import run_method
from plmarl_sitl.learning.eval.stats import mann_whitney_p, mean_ci95
from plmarl_sitl.learning.eval.suite import BATCH, episodes_per_mission, load_suite, twin_seeds
from plmarl_sitl.learning.nn.io import load_policy, script
from plmarl_sitl.learning.train.predictor import dead_reckoning_tracker


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("policy")
    p.add_argument("--family", default="failure_transit")
    p.add_argument("--tup", type=int, default=50)
    p.add_argument("--episodes", type=int, default=20)
    p.add_argument("--seed", type=int, default=2413)
    a = p.parse_args()
    torch.set_num_threads(1)
    _, fams = load_suite(PROJECT_SUITE)
    fam = fams[a.family]
    seeds = twin_seeds(a.seed, a.episodes, fam)
    counts = episodes_per_mission(a.episodes, len(fam.missions))
    lp = load_policy(a.policy, fam.missions[0])
    cv = script(dead_reckoning_tracker(int(lp.card["io"]["buffer_len"])))
    cov = {}
    for tracker_name, tracker in (("learnt", lp.tracker), ("cv", cv)):
        for sources in ("plan", "cv"):
            def make(env, tracker=tracker, sources=sources):  # noqa: ANN001, ANN202
                return LearnedController(tracker, lp.policy, env.mission, sources=sources)
            parts = [run_method(m.with_tup(a.tup), make, e, s[0], batch=BATCH, failure_prob=fam.spec.failure_prob).coverage
                     for m, e, s in zip(fam.missions, counts, seeds, strict=True) if e > 0]
            cov[f"tracker {tracker_name}, re-plan from {sources}"] = np.concatenate(parts)
            print(tracker_name, sources, float(cov[f"tracker {tracker_name}, re-plan from {sources}"].mean()), flush=True)
    ref = cov["tracker learnt, re-plan from plan"]
    print(json.dumps({"policy": a.policy, "family": a.family, "tup": a.tup, "episodes": a.episodes, "seed": a.seed,
                      "rows": {k: {"mean": mean_ci95(v)[0], "ci95": list(mean_ci95(v)[1]),
                                   "p_vs_pl_marl": mann_whitney_p(ref, v)} for k, v in cov.items()}}, indent=1))


if __name__ == "__main__":
    main()
