"""Session 19 probes on TRAINING twin seeds (< 1e9; never the suite's held-out seeds).

usage: PYTHONPATH=. python probe.py MISSION SEED EPISODES METHODS VARIANT[,VARIANT...]
VARIANT: 'as-is', 'refresh=S' (demand map every S s), 'speed=V' (user max speed m/s),
'tup=T'. Prints the mean coverage (t > 50 s) of each method per variant, and each method's
fraction of the best of the methods run, per episode, averaged.
"""

from __future__ import annotations

import dataclasses
import json
import sys

import numpy as np

from plmarl_sitl.learning.eval.evaluate import controller_factory, needed_policies, run_method
from plmarl_sitl.learning.nn.io import load_policy
from plmarl_sitl.learning.train.seeds import training_twin_seed
from plmarl_sitl.mission import load_mission


def variant(m, text: str):  # noqa: ANN001, ANN201
    if text == "as-is":
        return m
    key, val = text.split("=")
    if key == "refresh":
        return dataclasses.replace(m, demand=dataclasses.replace(m.demand, refresh_s=int(val)))
    if key == "speed":
        return dataclasses.replace(m, users=dataclasses.replace(m.users, max_speed_mps=float(val)))
    if key == "tup":
        return m.with_tup(int(val))
    raise SystemExit(f"unknown variant {text}")


def main() -> None:
    path, seed, episodes, methods, variants = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4].split(","), sys.argv[5].split(",")
    training_twin_seed(seed)  # refuses the evaluation range
    base = load_mission(path)
    loaded = {meth: load_policy(f"policies/{meth}", base) for meth in sorted(needed_policies(methods))}
    out = {"mission": path, "seed": seed, "episodes": episodes, "variants": {}}
    for v in variants:
        m = variant(base, v)
        cov = {meth: run_method(m, controller_factory(meth, loaded), episodes, seed).coverage for meth in methods}
        best = np.max(np.stack(list(cov.values())), 0)
        out["variants"][v] = {meth: {"coverage": float(c.mean()), "frac_of_best": float((c / best).mean())} for meth, c in cov.items()}
        print(v, {k: (round(x["coverage"], 4), round(x["frac_of_best"], 3)) for k, x in out["variants"][v].items()}, flush=True)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
