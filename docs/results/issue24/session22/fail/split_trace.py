"""Who hears whom and who knows what after a 2-of-6 failure at T_up 50 (service, the product),
in the episodes whose survivors' heard graph splits: per instant from 100 s, each live UAV's
position, the failed identities it knows, and the teammates it heard.

    PYTHONPATH=. python docs/results/issue24/session21/fail/split_trace.py SEED VARIANT(0 a, 1 b) [EPISODES]
"""
import sys

import numpy as np
import torch

from plmarl_sitl.learning.eval.controllers import ServiceController
from plmarl_sitl.learning.train.seeds import suite_twin_seed
from plmarl_sitl.mission import load_mission
from plmarl_sitl.twin.env import CoverageEnv

seed, v = int(sys.argv[1]), int(sys.argv[2])
eps = int(sys.argv[3]) if len(sys.argv) > 3 else 10
path = ["missions/suite/failure_2of6_a.yaml", "missions/suite/failure_2of6_b.yaml"][v]
m = load_mission(path).with_tup(50)
env = CoverageEnv(m, eps, suite_twin_seed(seed, v))
ctl = ServiceController(m)
ctl.reset()
obs = env.observe()
log: dict = {e: [] for e in range(eps)}
with torch.inference_mode():
    while not env.done:
        obs, _, info = env.step(ctl.act(obs))
        if obs.t >= 99 and obs.t % 50 in (0, 1, 2):
            inst = obs.t - obs.t % 50
            for e in range(eps):
                alive = env.alive[e].numpy()
                rows = []
                for i in np.flatnonzero(alive):
                    heard = np.flatnonzero(env.holdings.t_rx[e, i].numpy() == inst).tolist()
                    knows = np.flatnonzero(env.gossip.failed[e, i].numpy()).tolist()
                    tgt = ctl.targets.last[e, i].numpy().round(0).tolist()
                    rows.append(f"{i}@{env.pos[e, i, :2].numpy().round(0).tolist()}->{tgt} knows {knows} heard {heard}")
                log[e].append(f"  t={obs.t}: " + "; ".join(rows))
        cov = info.coverage
for e in range(eps):
    print(f"episode {e}:")
    print("\n".join(log[e]))
