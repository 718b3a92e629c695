# ruff: noqa  (a scratch probe kept to reproduce the numbers of session 20; not product code)
"""Session 20: why a student splits the swarm (training seed only). At each steady-state second
with lambda_2 = 0: is the distance graph (<= R_comm) split too (a link too long), or is it
connected by distance and cut by interference (SINR; typically two UAVs too close)?

    PYTHONPATH=. python docs/results/issue24/session20/learn/split_why.py probe_paper runs/l20/move-b 5002
"""
import sys
from pathlib import Path

import numpy as np
import torch

torch.set_num_threads(1)
from plmarl_sitl.learning.eval.controllers import LearnedController, ServiceController
from plmarl_sitl.learning.nn.io import load_policy
from plmarl_sitl.mission import load_mission
from plmarl_sitl.twin.env import CoverageEnv

HERE = Path(__file__).parent
name, pol, seed = sys.argv[1], sys.argv[2], int(sys.argv[3])
m = load_mission(name if "/" in name else HERE.parent.parent / "session19" / "move" / f"{name}.yaml").with_tup(15)


def comps(xy, r):
    n = len(xy)
    d = np.sqrt(((xy[:, None] - xy[None]) ** 2).sum(-1))
    adj = d <= r
    seen = np.zeros(n, bool); c = 0
    for s in range(n):
        if seen[s]:
            continue
        c += 1; st = [s]; seen[s] = True
        while st:
            k = st.pop(); nx = np.nonzero(adj[k] & ~seen)[0]; seen[nx] = True; st.extend(nx.tolist())
    return c


for label in ("service", pol):
    env = CoverageEnv(m, 20, seed, track_lambda2=True)
    if label == "service":
        ctl = ServiceController(m)
    else:
        lp = load_policy(Path(pol))
        ctl = LearnedController(lp.tracker, lp.policy, m)
    ctl.reset()
    obs = env.reset()
    n_split = n_dist = 0
    mind = []
    while not env.done:
        obs, _, info = env.step(ctl.act(obs))
        if obs.t <= 50:
            continue
        l2 = info.lambda2[:, -1] if info.lambda2.dim() > 1 else info.lambda2
        for b in np.nonzero((l2 <= 1e-6).numpy())[0]:
            xy = env.pos[b, :, :2].double().numpy()
            n_split += 1
            n_dist += comps(xy, float(m.radii.comm_m)) > 1
            d = np.sqrt(((xy[:, None] - xy[None]) ** 2).sum(-1)); np.fill_diagonal(d, np.inf)
            mind.append(d.min())
    mind = np.array(mind) if mind else np.array([np.nan])
    print(f"{label}: split seconds {n_split}, of which distance-split {n_dist}, interference-only {n_split - n_dist}; "
          f"min pair distance at split: median {np.median(mind):.0f} m, <100 m {np.mean(mind < 100):.2f}", flush=True)
