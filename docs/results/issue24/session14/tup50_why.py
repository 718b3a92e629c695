"""Issue 24, T_up 50: copy (E, A)'s plan-aware prediction of teammate J at each instant, its predicted SINR margin, and what A knows.

    PYTHONPATH=. python docs/results/issue24/session14/tup50_why.py SEED VARIANT MISSION TUP E A J
"""
import math
import sys

import numpy as np
import torch

from plmarl_sitl.learning.eval.controllers import ServiceController
from plmarl_sitl.learning.train.seeds import suite_twin_seed
from plmarl_sitl.mission import load_mission
from plmarl_sitl.model.gossip import _links
from plmarl_sitl.twin.env import CoverageEnv

seed, v, path, tup, e, a, j = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3], int(sys.argv[4]), int(sys.argv[5]), int(sys.argv[6]), int(sys.argv[7])
m = load_mission(path).with_tup(tup)
env = CoverageEnv(m, 10, suite_twin_seed(seed, v))
ctl = ServiceController(m, replan=True, sources="plan")
ctl.reset()
obs = env.observe()
done=set()
with torch.inference_mode():
    while not env.done:
        obs, _, info = env.step(ctl.act(obs))
        mo = ctl.targets.plans.motion
        for inst in (50, 100, 150, 200, 250):
            if env.t >= inst + 3 and inst not in done:
                done.add(inst)
                pred = mo.at(inst)[..., :3]
                s, d2 = _links(pred[e:e+1], torch.arange(6), pred[e:e+1, torch.arange(6), torch.arange(6)], m.channel)
                print(inst, "pred j", pred[e, a, j, :2].numpy().round(0), "pred a", pred[e, a, a, :2].numpy().round(0), "true j", env.pos[e, j, :2].numpy().round(0),
                      "d", round(math.sqrt(float(d2[0, a, j])),0), "sinr-thr dB", round(10*math.log10(float(s[0, a, j]))-m.channel.sinr_threshold_db, 1), "a knows", np.flatnonzero(env.gossip.failed[e, a].numpy()).tolist())
