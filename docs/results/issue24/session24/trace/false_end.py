"""H-trace24: a live UAV declared failed at the end (`pl-marl`, today's default): how it was declared, and why
nobody takes it back. Per new declaration of a live UAV: who, when, the positions, the distance and the SINR both
ways at the instant the declarer missed it; then at every later instant: who hears the declared UAV, who of those
holds the declaration, where each UAV is against its own plan point, and what each copy knows.

    PYTHONPATH=. python docs/results/issue24/session24/trace/false_end.py SEED VARIANT EPISODE TUP
"""
import sys

import numpy as np
import torch

from plmarl_sitl.learning.eval.evaluate import controller_factory
from plmarl_sitl.learning.nn.io import load_policy
from plmarl_sitl.learning.train.seeds import suite_twin_seed
from plmarl_sitl.mission import load_mission
from plmarl_sitl.model.graph import distances, link_mask
from plmarl_sitl.twin.env import CoverageEnv

seed, v, ep, tup = (int(x) for x in sys.argv[1:5])
assert 7 <= seed <= 14
path = ["missions/suite/failure_2of6_a.yaml", "missions/suite/failure_2of6_b.yaml"][v]
m = load_mission(path).with_tup(tup)
env = CoverageEnv(m, 10, suite_twin_seed(seed, v))
ctl = controller_factory("pl-marl", {"pl-marl": load_policy("policies/pl-marl")})(env)
ctl.reset()
plan = ctl.perceive.plan
obs = env.observe()
log = []
orig = env.run_signalling


def fmt(x) -> str:  # noqa: ANN001
    return str(np.round(x, 0).astype(int).tolist())


def hooked() -> None:
    t = env.t
    if t >= 95 and t % env.events.instant_tup(t) == 0:
        rx, sinr = link_mask(env.pos, env.alive, m.channel, m.radii.comm_m)
        rx, sinr, d = rx[ep].numpy(), sinr[ep].double().numpy(), distances(env.pos)[ep].numpy()
        alive = env.alive[ep].numpy()
        f = env.gossip.failed[ep].numpy()
        lf = [(a, j) for a in np.flatnonzero(alive) for j in np.flatnonzero(alive) if f[a, j]]
        if not (lf or t <= 100 + 2 * env.events.instant_tup(t)):  # a short line at every other instant
            log.append(f"  t={t} heard {({int(a): np.flatnonzero(rx[a] & alive).tolist() for a in np.flatnonzero(alive)})}")
        else:
            heard = {int(a): np.flatnonzero(rx[a] & alive).tolist() for a in np.flatnonzero(alive)}
            own = plan.last[ep].double().numpy() if plan.last is not None else None
            rows = [f"  t={t} heard {heard}; live declared (holder, live) {lf}"]
            for a in np.flatnonzero(alive):
                cf = np.flatnonzero(plan.plans.failed[ep, a]).tolist() if plan.plans is not None and plan.plans.failed is not None else []
                pt = "" if own is None else f" point {fmt(own[a])} off {np.linalg.norm(env.pos[ep, a, :2].numpy() - own[a]):.0f}"
                rows.append(f"    {a}: pos {fmt(env.pos[ep, a, :2].numpy())}{pt} knows {np.flatnonzero(f[a]).tolist()} "
                            f"since {env.gossip.since[ep, a].numpy()[f[a]].tolist()} copy failed {cf}")
            for a, j in lf:
                rows.append(f"    {a}-{j}: d {d[a, j]:.0f} sinr {10 * np.log10(max(sinr[a, j], 1e-12)):.1f}/{10 * np.log10(max(sinr[j, a], 1e-12)):.1f} dB "
                            f"{a} hears {j}: {bool(rx[a, j])}, {j} hears {a}: {bool(rx[j, a])}")
            log.append("\n".join(rows))
    orig()


env.run_signalling = hooked
prev = env.gossip.failed.clone()
with torch.inference_mode():
    while not env.done:
        t = obs.t
        obs, _, info = env.step(ctl.act(obs))
        f = env.gossip.failed
        new = f & ~prev & env.alive.unsqueeze(1) & env.alive.unsqueeze(-1)
        for e, a, j in torch.nonzero(new).tolist():
            if e == ep:
                log.append(f"DECISION t={t}..{obs.t}: {a} now holds live {j} failed since {int(env.gossip.since[e, a, j])}; "
                           f"pos {a} {fmt(env.pos[e, a, :2].numpy())} {j} {fmt(env.pos[e, j, :2].numpy())} "
                           f"d {float(torch.linalg.vector_norm(env.pos[e, a] - env.pos[e, j])):.0f}; "
                           f"{a} held {j} last at {float(obs.nbr_t_rx[e, a, j]):.0f}; {a}'s copy (failed "
                           f"{np.flatnonzero(plan.plans.failed[e, a]).tolist()}) puts {j} at {fmt(plan.copy_points()[e, a, j].numpy())}, "
                           f"{j}'s own copy (failed {np.flatnonzero(plan.plans.failed[e, j]).tolist()}) at {fmt(plan.copy_points()[e, j, j].numpy())}; "
                           f"{a}'s prediction of {j} at instant {int(env.gossip.since[e, a, j])}: "
                           f"{fmt(plan.plans.motion.at(int(env.gossip.since[e, a, j]))[e, a, j, :2].numpy())}")
        prev = f.clone()
alive = env.alive
print(f"seed {seed} {'ab'[v]} episode {ep} T_up {tup}; dead {np.flatnonzero(~alive[ep].numpy()).tolist()}")
print("\n".join(log))
print("end: live declared (episode, holder, live):",
      [(e, a, j) for e, a, j in torch.nonzero(env.gossip.failed & alive.unsqueeze(1) & alive.unsqueeze(-1)).tolist() if e == ep])
