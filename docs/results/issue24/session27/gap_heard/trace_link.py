"""At the decision after instant K: copy A's plan-aware prediction of J and itself at K and at the instant before,
the true positions at K, SINR margins (predicted) and R_comm."""
import sys, math, torch
from plmarl_sitl.learning.eval.controllers import LearnedController
from plmarl_sitl.learning.nn.io import load_policy
from plmarl_sitl.mission import load_mission
from plmarl_sitl.model.gossip import _links, _own_rows
from plmarl_sitl.twin.env import CoverageEnv
path, seed, K, P, A, J = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4]), int(sys.argv[5]), int(sys.argv[6])
m = load_mission(path)
lp = load_policy("policies/pl-marl", m)
env = CoverageEnv(m, 1, seed)
ctl = LearnedController(lp.tracker, lp.policy, m)
ctl.reset(); obs = env.observe()
true = {}
while not env.done:
    true[int(obs.t)] = env.pos[0, :, :3].clone() if hasattr(env, 'pos') else obs.ego[0, :, :3].clone()
    obs, _, info = env.step(ctl.act(obs))
    if obs.t >= K + 1 and "done" not in true:
        true["done"] = 1
        mo = ctl.perceive.plan.plans.motion
        for at in (P, K):
            pr = mo.at(at)[0, A, :, :3]
            print(f"instant {at}: predicted A {pr[A].tolist()} J {pr[J].tolist()} d {float((pr[A]-pr[J]).norm()):.0f} m; true A {true[max(k for k in true if isinstance(k,int) and k<=at)][A].tolist()} J {true[max(k for k in true if isinstance(k,int) and k<=at)][J].tolist()} d {float((true[max(k for k in true if isinstance(k,int) and k<=at)][A]-true[max(k for k in true if isinstance(k,int) and k<=at)][J]).norm()):.0f} m")
            pred = mo.at(at)[..., :3]
            sinr, d2 = _links(pred, torch.arange(env.n), _own_rows(pred, torch.arange(env.n)), m.channel)
            print(f"   predicted margin {10*math.log10(float(sinr[0, A, J])) - m.channel.sinr_threshold_db:+.1f} dB, d {math.sqrt(float(d2[0, A, J])):.0f} m, R_comm {m.radii.comm_m}")
        print("t_rx of A:", obs.nbr_t_rx[0, A].tolist())
        break
