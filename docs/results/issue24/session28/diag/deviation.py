"""Deviation of each live UAV's true position from the plan-aware nominal (copy of agent 0... each agent's own copy row j=j),
per decision, pl-marl vs service, for a suite family batch (tuning seed)."""
import sys, os
import numpy as np, torch
from plmarl_sitl.learning.eval.evaluate import controller_factory
from plmarl_sitl.learning.eval.suite import load_suite, episodes_per_mission, twin_seeds
from plmarl_sitl.learning.nn.io import load_policy
from plmarl_sitl.twin.env import CoverageEnv
fam_name, tup, seed = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
V = int(os.environ.get("V", "0"))
spec, fams = load_suite("/work/main/missions/suite/suite.yaml")
fam = fams[fam_name]
m = fam.missions[V].with_tup(tup)
n_ep = episodes_per_mission(30, len(fam.missions))[V]
s = twin_seeds(seed, 30, fam)[V][0]
loaded = {"pl-marl": load_policy(os.environ.get("POL", "/work/main/policies/pl-marl"), m)}
for meth in ["pl-marl", "service"]:
    env = CoverageEnv(m, n_ep, s, track_lambda2=True, failure_prob=fam.spec.failure_prob)
    ctl = controller_factory(meth, loaded)(env); ctl.reset(); obs = env.observe()
    tg = ctl.targets if hasattr(ctl, "targets") else ctl.perceive.plan
    devs = []
    with torch.inference_mode():
        while not env.done:
            act = ctl.act(obs)
            mo = tg.plans.motion if tg.plans is not None else None
            if mo is None or mo.t != int(obs.t):
                obs, _, info = env.step(act); continue
            nom = mo.now  # (B, A, n, 6)
            n = nom.shape[2]
            own_copy = nom[:, np.arange(n), np.arange(n), :2]  # each agent's own nominal
            true = obs.ego[..., :2].double().numpy()
            d = np.linalg.norm(true - own_copy, axis=-1)
            d[~env.alive.numpy()] = np.nan
            devs.append((int(obs.t), d))
            obs, _, info = env.step(act)
    ts = np.array([t for t, _ in devs]); D = np.stack([d for _, d in devs])  # T,E,n
    print(meth)
    for lo, hi in [(0, 30), (30, 60), (60, 100), (100, 150), (150, 250)]:
        sel = (ts > lo) & (ts <= hi)
        x = D[sel]
        print(f"  t in ({lo},{hi}]: median {np.nanmedian(x):.1f} m, p90 {np.nanpercentile(x,90):.1f}, max {np.nanmax(x):.1f}")
