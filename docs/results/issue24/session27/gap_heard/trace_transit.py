"""Trace new failure declarations (t, knower, identity, identity alive?) in one twin episode of the gap's seed,
with the heard-link rule on or off, and coverage per 25 s."""
import sys, torch
from plmarl_sitl.learning.eval.controllers import LearnedController
from plmarl_sitl.learning.nn.io import load_policy
from plmarl_sitl.mission import load_mission
from plmarl_sitl.model import gossip
from plmarl_sitl.twin.env import CoverageEnv
path, seed, margin = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
gossip.HEARD_MARGIN_DB = margin
m = load_mission(path)
lp = load_policy("policies/pl-marl", m)
env = CoverageEnv(m, 1, seed)
ctl = LearnedController(lp.tracker, lp.policy, m)
ctl.reset(); obs = env.observe()
prev = env.gossip.failed.clone()
cov = []
while not env.done:
    obs, _, info = env.step(ctl.act(obs))
    cov.extend(info.coverage[0].tolist())
    f = env.gossip.failed[0]
    new = f & ~prev[0]
    gone = prev[0] & ~f
    for a, j in zip(*torch.nonzero(new, as_tuple=True)):
        print(f"t={obs.t} {int(a)} declares {int(j)} ({'alive' if env.alive[0, j] else 'dead'}), knower alive {bool(env.alive[0, a])}")
    for a, j in zip(*torch.nonzero(gone, as_tuple=True)):
        print(f"t={obs.t} {int(a)} takes back {int(j)}")
    prev = env.gossip.failed.clone()
print("coverage per 25 s:", [round(sum(cov[i:i+25])/25, 3) for i in range(0, len(cov), 25)])
print("mean", sum(cov)/len(cov))
