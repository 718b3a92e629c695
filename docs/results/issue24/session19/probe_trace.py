"""Session 19: where in the episode a method loses coverage (TRAINING twin seeds only).

usage: PYTHONPATH=. python probe_trace.py MISSION SEED EPISODES TUP METHODS
Prints each method's mean coverage C(t) at a few seconds, and its mean lambda_2 (t > 50 s).
"""

from __future__ import annotations

import sys

from plmarl_sitl.learning.eval.evaluate import controller_factory, needed_policies, run_method
from plmarl_sitl.learning.nn.io import load_policy
from plmarl_sitl.learning.train.seeds import training_twin_seed
from plmarl_sitl.mission import load_mission

AT = (20, 40, 60, 80, 100, 120, 150, 200, 250, 299)


def main() -> None:
    path, seed, episodes, tup, methods = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), sys.argv[5].split(",")
    training_twin_seed(seed)
    m = load_mission(path).with_tup(tup)
    loaded = {meth: load_policy(f"policies/{meth}", m) for meth in sorted(needed_policies(methods))}
    print("t:", AT)
    for meth in methods:
        r = run_method(m, controller_factory(meth, loaded), episodes, seed)
        tr = r.trace.mean(0)
        print(f"{meth:15s}", " ".join(f"{tr[min(t, len(tr) - 1)]:.3f}" for t in AT), f"lambda2 {r.lambda2.mean():.2f}", flush=True)


if __name__ == "__main__":
    main()
