"""Session 22 diagnostic: when each live UAV is first held failed, by whom, under c4 (DECLARE_PRE_REPLAN, K = 1, PRE_REPLAN_SEEN), and the live declarations left at the end.

    PYTHONPATH=. python docs/results/issue24/session22/fail/diag_false_end.py SEED VARIANT
"""
import sys
import numpy as np, torch
from plmarl_sitl.learning.eval.controllers import ServiceController
from plmarl_sitl.learning.train.seeds import suite_twin_seed
from plmarl_sitl.mission import load_mission
from plmarl_sitl.twin.env import CoverageEnv
from plmarl_sitl.learning.nn import plan as plan_mod
plan_mod.DECLARE_PRE_REPLAN = True; plan_mod.PRE_REPLAN_MISSED = 1; plan_mod.PRE_REPLAN_SEEN = True
seed, v = int(sys.argv[1]), int(sys.argv[2])
path = ["missions/suite/failure_2of6_a.yaml", "missions/suite/failure_2of6_b.yaml"][v]
m = load_mission(path).with_tup(50)
env = CoverageEnv(m, 10, suite_twin_seed(seed, v))
ctl = ServiceController(m); ctl.reset(); obs = env.observe()
prev = env.gossip.failed.clone()
with torch.inference_mode():
    while not env.done:
        t = obs.t
        obs, _, info = env.step(ctl.act(obs))
        f = env.gossip.failed
        new = f & ~prev & env.alive.unsqueeze(1) & env.alive.unsqueeze(-1)
        for e, a, j in torch.nonzero(new).tolist():
            print(f"t={t} ep {e}: {a} now holds live {j} failed since {int(env.gossip.since[e,a,j])}; pos a {env.pos[e,a,:2].numpy().round(0)} j {env.pos[e,j,:2].numpy().round(0)} a knows {np.flatnonzero(f[e,a].numpy()).tolist()}")
        prev = f.clone()
alive = env.alive
print("end false:", [(e, a, j) for e, a, j in torch.nonzero(env.gossip.failed & alive.unsqueeze(1) & alive.unsqueeze(-1)).tolist()])
