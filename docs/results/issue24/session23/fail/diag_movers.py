"""Session 23: how many survivors the fewest-movers re-plan moves, per re-plan step of a copy
(twin; `service`, T_up 50, replan way; tuning seeds only).

    PYTHONPATH=. python docs/results/issue24/session23/fail/diag_movers.py SEED [MARGIN_FRAC]
"""
import sys
from collections import Counter

import numpy as np
import torch

from plmarl_sitl.learning.eval.controllers import ServiceController
from plmarl_sitl.learning.train.seeds import suite_twin_seed
from plmarl_sitl.mission import load_mission
from plmarl_sitl.model import service
from plmarl_sitl.twin.env import CoverageEnv

service.FEWEST_MOVERS = True
service.MOVERS_MARGIN_FRAC = float(sys.argv[2]) if len(sys.argv) > 2 else 0.0
seen: Counter = Counter()
orig = service.TeamPlans._fewest_movers


def counted(self, b, a, counts, alive, src):  # noqa: ANN001, ANN202
    out = orig(self, b, a, counts, alive, src)
    if out is not None:
        rows = self.slot[b, a, alive]
        old = self.points[b, a, rows]
        pts, own = out
        seen[int((np.abs(pts[own] - old).sum(-1) > 0).sum())] += 1
    else:
        seen["no old point"] += 1
    return out


service.TeamPlans._fewest_movers = counted
seed = int(sys.argv[1])
for v, path in enumerate(["missions/suite/failure_2of6_a.yaml", "missions/suite/failure_2of6_b.yaml"]):
    m = load_mission(path).with_tup(50)
    env = CoverageEnv(m, 10, suite_twin_seed(seed, v))
    ctl = ServiceController(m)
    ctl.reset()
    obs = env.observe()
    seen.clear()
    with torch.inference_mode():
        while not env.done:
            obs, _, _ = env.step(ctl.act(obs))
    print(path.split("/")[-1], "movers per re-plan step (of the copies' steps):", dict(sorted(seen.items(), key=str)))
