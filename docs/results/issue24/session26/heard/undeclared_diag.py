"""Diagnostic (session 26): failures nobody declares. For each episode whose survivors never all
learn a failure, per failed UAV f and survivor a: heard f at instant 50? predicted distance and SINR
a<-f at instant 100 (the plan-aware prediction), real distance at 100, and which rule could fire."""
import sys
import numpy as np
import torch
from plmarl_sitl.learning.eval.controllers import ServiceController
from plmarl_sitl.learning.train.seeds import suite_twin_seed
from plmarl_sitl.mission import load_mission
from plmarl_sitl.model.channel import u2u_sinr, db_to_lin
from plmarl_sitl.model.gossip import clear_hearing, steady_links, _links
import math
from plmarl_sitl.twin.env import CoverageEnv

path, seed, tup, eps = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), int(sys.argv[4])
m = load_mission(path).with_tup(tup)
env = CoverageEnv(m, eps, suite_twin_seed(seed, 0, 0), failure_prob=0.0)
ctl = ServiceController(m, replan=True, sources="plan")
ctl.reset()
obs = env.observe()
snap = {}
with torch.inference_mode():
    while not env.done:
        obs, _, info = env.step(ctl.act(obs))
        if obs.t < 100:
            snap[99] = dict(t_rx=obs.nbr_t_rx.clone(), pos=obs.ego[..., :3].clone())
        if obs.t >= 100 and 101 not in snap:
            snap[101] = dict(t_rx=obs.nbr_t_rx.clone(), pos=obs.ego[..., :3].clone())
            if True:
                mo = ctl.targets.plans.motion
                snap["pred100"] = mo.at(100)[..., :3].clone()
                snap["pred50"] = mo.at(50)[..., :3].clone()
alive = env.alive
known = env.gossip.failed
n = env.n
ch, comm = m.channel, float(m.radii.comm_m)
print("R_comm", comm)
for b in range(eps):
    dead = np.flatnonzero(~alive[b].numpy())
    live = np.flatnonzero(alive[b].numpy())
    undeclared = [f for f in dead if not known[b][live][:, f].all()]
    if not undeclared:
        continue
    print(f"episode {b}: dead {dead.tolist()}, not known by all: {undeclared}; who knows:",
          {int(f): [int(a) for a in live if known[b, a, f]] for f in dead})
    pred = snap["pred100"][b]  # (N copies, N ids, 3)
    pred50 = snap["pred50"][b]
    for f in dead:
        for a in live:
            rx = snap[101]["t_rx"][b, a, f].item()
            dp = float((pred[a, a] - pred[a, f]).norm())
            dr = float((snap[99]["pos"][b, a] - snap[99]["pos"][b, f]).norm())
            ch_ = clear_hearing(pred[a][None], torch.tensor([a]), pred[a, a][None], ch, comm)[0, f].item()
            st = steady_links(pred[a][None], pred50[a][None], torch.tensor([a]), ch, comm)[0, f].item()
            sinr, _ = _links(pred[a][None], torch.tensor([a]), pred[a, a][None], ch)
            marg = 10 * math.log10(max(float(sinr[0, f]), 1e-12)) - ch.sinr_threshold_db
            print(f"   margin {marg:+.1f} dB", end="")
            print(f"   f={f} a={a}: last heard f at {rx:.0f}, predicted d@100 {dp:.0f} m, real d@99 {dr:.0f} m, clear {ch_}, steady {st}, moved f {float((pred[a,f]-pred50[a,f]).norm()):.0f} m, a {float((pred[a,a]-pred50[a,a]).norm()):.0f} m")
