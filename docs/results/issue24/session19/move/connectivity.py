# ruff: noqa  (a scratch probe kept to reproduce the numbers in docs/RESULTS.md, session 19; not product code)
"""Session 19 probe (training twin seeds): what following the sensed users costs the swarm's
connectivity: share of steady-state seconds (t > 50 s) with lambda_2 = 0 (the live swarm split),
mean lambda_2, coverage, and copies re-planned on false failure declarations (no UAV fails here).

    PYTHONPATH=. python docs/results/issue24/session19/move/connectivity.py probe_paper,probe_random 0,30,60 [keep]
"""
import sys
from pathlib import Path

import torch

torch.set_num_threads(1)
from plmarl_sitl.learning.eval.controllers import ServiceController
from plmarl_sitl.mission import load_mission
from plmarl_sitl.twin.rollout import rollout

HERE = Path(__file__).parent
for name in sys.argv[1].split(","):
    base = load_mission(name if "/" in name else HERE / f"{name}.yaml")
    for tup in (15, 50):
        for d in [float(x) for x in sys.argv[2].split(",")]:
            ctls = []
            def make(env, d=d):
                m = env.mission.with_track_sensed(d)
                if len(sys.argv) > 3:
                    m = __import__("dataclasses").replace(m, track_keep_links=True)
                c = ServiceController(m); ctls.append(c); return c
            r = rollout(base.with_tup(tup), make, 20, 4343, batch=20)[0]
            l2 = r.lambda2[:, 50:]
            print(f"{name} T_up {tup} track {d:4.0f}: coverage {float(r.coverage[:, 50:].mean()):.4f} lambda2 {float(l2.mean()):.3f} "
                  f"split {float((l2 <= 1e-6).double().mean()):.3f} re-planned copies {sum(c.targets.replans_done for c in ctls)}", flush=True)
