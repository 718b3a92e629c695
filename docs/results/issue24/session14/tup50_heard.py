"""Issue 24, T_up 50: per episode, instants after the failure at which the survivors' heard graph is split, and survivor-instants not knowing every failure.

    PYTHONPATH=. python docs/results/issue24/session14/tup50_heard.py SEED VARIANT MISSION TUP
"""
import sys

import numpy as np
import torch

from plmarl_sitl.learning.eval.controllers import ServiceController
from plmarl_sitl.learning.train.seeds import suite_twin_seed
from plmarl_sitl.mission import load_mission
from plmarl_sitl.model.graph import link_mask
from plmarl_sitl.twin.env import CoverageEnv

seed, v, path, tup = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3], int(sys.argv[4])
m = load_mission(path).with_tup(tup)
env = CoverageEnv(m, 10, suite_twin_seed(seed, v))
ctl = ServiceController(m, replan=True, sources="plan")
ctl.reset()
obs = env.observe()
split = np.zeros(10, int)
unknown = np.zeros(10, int)
rows = 0
last = -1
with torch.inference_mode():
    while not env.done:
        obs, _, info = env.step(ctl.act(obs))
        k = env.t // tup
        if k != last and env.t > 100:
            last = k
            rx, _ = link_mask(env.pos, env.alive, m.channel, m.radii.comm_m)
            for b in range(10):
                live = np.flatnonzero(env.alive[b].numpy())
                a = (rx[b].numpy() | rx[b].numpy().T)[np.ix_(live, live)]
                # components
                seen = {0}
                stack = [0]
                while stack:
                    i = stack.pop()
                    for j in np.flatnonzero(a[i]):
                        if j not in seen:
                            seen.add(j)
                            stack.append(j)
                conn = len(seen) == len(live)
                dead = ~env.alive[b].numpy()
                know = (env.gossip.failed[b].numpy()[live][:, dead]).all(1)
                split[b] += not conn
                unknown[b] += (~know).sum()
            rows += 1
print(path[-6:], "tup", tup, "instants after 100:", rows, "episodes with survivors' heard graph split at some instant:", int((split>0).sum()), "split instants per episode:", split.tolist(), "survivor-instants not knowing all:", unknown.tolist())
