"""Session 22 diagnostic: every declaration the pre-re-plan rule makes (DECLARE_PRE_REPLAN, K = 1; a third argument: PRE_REPLAN_SEEN), live or dead, with the positions and knowledge behind it.

    PYTHONPATH=. python docs/results/issue24/session22/fail/diag_declared.py SEED VARIANT [seen]
"""
import sys
import numpy as np, torch
from plmarl_sitl.learning.eval.controllers import ServiceController
from plmarl_sitl.learning.train.seeds import suite_twin_seed
from plmarl_sitl.mission import load_mission
from plmarl_sitl.twin.env import CoverageEnv
from plmarl_sitl.learning.nn import plan as plan_mod
from plmarl_sitl.model.gossip import key_of, since_of
plan_mod.DECLARE_PRE_REPLAN = True
plan_mod.PRE_REPLAN_MISSED = 1
plan_mod.PRE_REPLAN_SEEN = len(sys.argv) > 3
seed, v = int(sys.argv[1]), int(sys.argv[2])
path = ["missions/suite/failure_2of6_a.yaml", "missions/suite/failure_2of6_b.yaml"][v]
m = load_mission(path).with_tup(50)
env = CoverageEnv(m, 10, suite_twin_seed(seed, v))
ctl = ServiceController(m); ctl.reset(); obs = env.observe()
orig = plan_mod.ServiceTargets._pre_replan_suspects
T = {'t': 0}
def wrapped(self, blocked, missed, gossip, *rest):
    out = orig(self, blocked, missed, gossip, *rest)
    for e, a, j in zip(*[x.tolist() for x in torch.nonzero(out, as_tuple=True)]):
        live = bool(env.alive[e, j])
        c = plan_mod._pre_replan_candidates(self.plans, e, a, j, gossip.heard_rank[e, a, j])
        pred = self.plans.motion.at_array(missed[0])[e, a]
        print(f"t={T['t']} ep {e}: {a} declares {j} live={live} missed {missed} true_j {env.pos[e,j,:2].numpy().round(0)} true_a {env.pos[e,a,:2].numpy().round(0)} "
              f"pred_a {pred[a,:2].round(0)} pred_j {pred[j,:2].round(0)} cands {[x.round(0).tolist() for x in c]} "
              f"j_knows {np.flatnonzero((key_of(gossip.heard_rank[e,a,j])%2==1).numpy()).tolist()} at {since_of(gossip.heard_rank[e,a,j]).numpy().tolist()} a_knows {np.flatnonzero(gossip.failed[e,a].numpy()).tolist()} {gossip.since[e,a].numpy().tolist()} "
              f"true j knows {np.flatnonzero(gossip.failed[e,j].numpy()).tolist()}")
    return out
plan_mod.ServiceTargets._pre_replan_suspects = wrapped
with torch.inference_mode():
    while not env.done:
        T['t'] = obs.t
        obs, _, info = env.step(ctl.act(obs))
