import sys, os
import numpy as np, torch
from plmarl_sitl.learning.eval.evaluate import controller_factory
from plmarl_sitl.learning.eval.suite import load_suite, episodes_per_mission, twin_seeds
from plmarl_sitl.learning.nn.io import load_policy
from plmarl_sitl.twin.env import CoverageEnv
fam_name, tup, seed = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
pol = sys.argv[4] if len(sys.argv) > 4 else "/work/main/policies/pl-marl"
spec, fams = load_suite("/work/main/missions/suite/suite.yaml")
fam = fams[fam_name]; m = fam.missions[0].with_tup(tup)
s = twin_seeds(seed, 30, fam)[0][0]
loaded = {"pl-marl": load_policy(pol, m)}
for meth in ["pl-marl", "service"]:
    env = CoverageEnv(m, 30, s, failure_prob=fam.spec.failure_prob)
    ctl = controller_factory(meth, loaded)(env); ctl.reset(); obs = env.observe()
    rows = []
    with torch.inference_mode():
        while not env.done:
            act = ctl.act(obs)
            v = obs.ego[..., 3:6].double().numpy(); sp = np.linalg.norm(v[..., :2], axis=-1)
            a = act.double().numpy(); an = np.linalg.norm(a[..., :2], axis=-1)
            rows.append((int(obs.t), np.median(sp), np.median(an), np.median(-obs.ego[..., 2].double().numpy()), np.median(v[..., 2])))
            obs, _, _ = env.step(act)
    print(meth)
    for r in rows[:30:2]:
        print("  t=%3d speed_xy med %.2f  |a_xy| med %.2f  alt %.1f vz %.2f" % r)
