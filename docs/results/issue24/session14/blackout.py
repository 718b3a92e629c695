"""Coverage on blackout.yaml (service, T_up 15) after 50 s / 150 s, and live UAVs declared at the end.
Run with PYTHONPATH set to the checkout under test.  usage: blackout.py SEED_RUN EPISODES [TUP]"""
import sys, time, torch
import plmarl_sitl
from plmarl_sitl.mission import load_mission
from plmarl_sitl.twin.env import CoverageEnv
from plmarl_sitl.learning.eval.controllers import ServiceController
from plmarl_sitl.learning.train.seeds import suite_twin_seed
run, eps = int(sys.argv[1]), int(sys.argv[2])
tup = int(sys.argv[3]) if len(sys.argv) > 3 else 15
root = plmarl_sitl.__file__.rsplit('/plmarl_sitl/', 1)[0]
m = load_mission(root + '/missions/blackout.yaml').with_tup(tup)
seed = suite_twin_seed(run, 0)
t0 = time.time()
env = CoverageEnv(m, eps, seed)
ctl = ServiceController(m); ctl.reset()
obs = env.observe(); cov = []
while not env.done:
    obs, _, info = env.step(ctl.act(obs)); cov.append(info.coverage)
c = torch.cat(cov, -1)  # (B, T)
T = c.shape[-1]
a50 = c[:, 50:].mean(-1); a150 = c[:, 150:].mean(-1)
live = env.alive
false = (env.gossip.failed & live.unsqueeze(-1) & live.unsqueeze(-2)).sum().item()
ever = getattr(env.gossip, 'key', None)
bumps = int((ever // 2).sum()) if ever is not None else 0
print(f"code={root} run_seed={run} twin_seed={seed} episodes={eps} tup={tup} T={T}")
print(f"cov>50s mean={a50.mean():.4f} cov>150s mean={a150.mean():.4f} per-episode>150={[round(x,3) for x in a150.tolist()]}")
print(f"live pairs declared at end={false} incarnation bumps(sum over copies)={bumps} wall={time.time()-t0:.0f}s")
