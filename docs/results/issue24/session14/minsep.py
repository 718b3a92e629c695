"""min live-pair separation (whole episode and from the failure on) and live UAVs sharing a target at the end;
service, the 2-of-6 families. usage: minsep.py RUN_SEED EPISODES"""
import sys, torch
import plmarl_sitl
from plmarl_sitl.mission import load_mission
from plmarl_sitl.twin.env import CoverageEnv
from plmarl_sitl.learning.eval.controllers import ServiceController
from plmarl_sitl.learning.train.seeds import suite_twin_seed
root = plmarl_sitl.__file__.rsplit('/plmarl_sitl/', 1)[0]
run, eps = int(sys.argv[1]), int(sys.argv[2])
for v, name in enumerate(["failure_2of6_a", "failure_2of6_b"]):
    for tup in (15, 50):
        m = load_mission(f"{root}/missions/suite/{name}.yaml").with_tup(tup)
        env = CoverageEnv(m, eps, suite_twin_seed(run, v))
        ctl = ServiceController(m); ctl.reset(); obs = env.observe()
        ms_all = torch.full((eps,), float("inf")); ms_after = ms_all.clone()
        while not env.done:
            obs, _, info = env.step(ctl.act(obs))
            s = info.min_separation.flatten()
            ms_all = torch.minimum(ms_all, s)
            if env.t >= 100:
                ms_after = torch.minimum(ms_after, s)
        tg = ctl.targets.last; shared = 0
        for b in range(eps):
            live = env.alive[b]
            p = tg[b][live]
            d = torch.cdist(p, p) + torch.eye(len(p)) * 1e9
            shared += int((d < 1.0).any())
        print(f"{name} tup={tup} seed={suite_twin_seed(run, v)} min_sep_all={ms_all.min():.2f} min_sep_after_failure median={ms_after.median():.1f} min={ms_after.min():.2f} episodes<5m={int((ms_after<5).sum())}/{eps} shared_target_end={shared}/{eps}", flush=True)
