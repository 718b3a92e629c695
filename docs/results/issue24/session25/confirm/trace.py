"""H-confirm25, Task 1: trace one episode (default seed 19, mission a, episode 2, T_up 50, way replan), base and LR.

    PYTHONPATH=. python docs/results/issue24/session25/confirm/trace.py [--local-repairs] [--controller pl-marl] > OUT

Flies the whole batch of the cell (the episodes share one env, so episode E is the one decompose.py flies) and logs,
for episode E only:
* at each signalling instant, who heard whom (i <- j) and the true positions of the live UAVs;
* at every decision, each copy's knowledge (declared failed set with instants) when it changes;
* each own declaration (copy a declares j at decision t): j's true state (alive?), when a last heard j, the
  missed instants, a's predicted position of j there against j's true position (distance), whether the
  prediction was `clear hearing`, and what j's last message to a knew (the may_predict guard's input);
* the copies' LR / CR steps (session24/local/decompose.py's --cr-log line format), with the copy's plan points;
* per second after the failure, C(t).
"""
from __future__ import annotations

import argparse
import importlib.util
import sys

import numpy as np
import torch

spec = importlib.util.spec_from_file_location("dec", "docs/results/issue24/session24/local/decompose.py")
dec = importlib.util.module_from_spec(spec)
spec.loader.exec_module(dec)  # installs the CR/LR step logger on TeamPlans._compose

from plmarl_sitl.learning.eval.controllers import ServiceController  # noqa: E402
from plmarl_sitl.learning.eval.evaluate import controller_factory  # noqa: E402
from plmarl_sitl.learning.nn import plan as plan_mod  # noqa: E402
from plmarl_sitl.learning.nn.io import load_policy  # noqa: E402
from plmarl_sitl.learning.train.seeds import suite_twin_seed  # noqa: E402
from plmarl_sitl.mission import load_mission  # noqa: E402
from plmarl_sitl.model import gossip as gossip_mod  # noqa: E402
from plmarl_sitl.model import service as service_mod  # noqa: E402
from plmarl_sitl.twin.env import CoverageEnv  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("--seed", type=int, default=19)
ap.add_argument("--mission", default="missions/suite/failure_2of6_a.yaml")
ap.add_argument("--variant", type=int, default=0)
ap.add_argument("--episode", type=int, default=2)
ap.add_argument("--episodes", type=int, default=10)
ap.add_argument("--tup", type=int, default=50)
ap.add_argument("--controller", default="pl-marl")
ap.add_argument("--local-repairs", action="store_true")
a = ap.parse_args()
E = a.episode
service_mod.COMPOSE_REPAIRS = a.local_repairs
service_mod.LOCAL_REPAIRS = a.local_repairs
dec.CR["log"] = sys.stdout
for k in ("steps", "fallback", "repairs", "movers", "nonbr"):
    dec.CR[k] = np.zeros(a.episodes, int)
dec.CR["row"] = "STEP"

POS: dict[int, np.ndarray] = {}  # second -> (N, 3) true positions of episode E
ALIVE: dict[int, np.ndarray] = {}
STATE = {"t": -1, "plans": None, "instants": None, "gossip": None, "t_rx": None}

_on_failures = plan_mod.ServiceTargets.on_failures


def _fmt(xy: np.ndarray) -> str:
    return f"({xy[0]:7.1f},{xy[1]:7.1f})"


def on_failures(self, t, mask, alive, gossip, t_rx, ego, held):  # noqa: ANN001, ANN202
    before = gossip.failed[E].clone()
    STATE.update(t=t, plans=self.plans, instants=self.instants, gossip=gossip, t_rx=t_rx, comm=self.comm_m, channel=self.channel)
    recent = self.instants.recent(t, self.declare_after + 1)
    missed = recent[: self.declare_after]
    guard = gossip_mod.may_predict(gossip.heard_rank, gossip.rank, self.instants.last(t))[E].clone()
    hr = gossip.heard_rank[E].clone()
    out = _on_failures(self, t, mask, alive, gossip, t_rx, ego, held)
    after = gossip.failed[E]
    new_own = after & ~before
    n = after.shape[-1]
    for i, j in zip(*torch.nonzero(new_own, as_tuple=True)):
        i, j = int(i), int(j)
        # own declaration now, or merged? on_failures only declares; merges happen in env.step (receive)
        last = float(t_rx[E, i, j])
        line = [f"DECLARE t {t}: copy {i} declares {j} ({'ALIVE' if bool(alive[E, j]) else 'dead'}); last heard {last:.0f}; missed {missed}; recent {recent}"]
        for at in missed + ([recent[-1]] if len(recent) > len(missed) else []):
            pred = self.plans.motion.at(at)[E, i, j, :2].numpy()
            own = self.plans.motion.at(at)[E, i, i, :2].numpy()
            true = POS[at][j, :2] if at in POS else np.full(2, np.nan)
            truei = POS[at][i, :2] if at in POS else np.full(2, np.nan)
            line.append(f"   at {at}: predicted j {_fmt(pred)} true j {_fmt(true)} (off {np.hypot(*(pred - true)):.0f} m); "
                        f"predicted i {_fmt(own)} true i {_fmt(truei)}; predicted dist {np.hypot(*(pred - own)):.0f} m, true dist {np.hypot(*(true - truei)):.0f} m")
        ar = torch.arange(n)
        for at in missed:
            pr = self.plans.motion.at(at)[..., :3]
            ch = gossip_mod.clear_hearing(pr, ar, pr[:, ar, ar], self.channel, self.comm_m)[E, i, j]
            line.append(f"   rule at {at}: clear hearing (suspects) {bool(ch)}")
            if len(recent) > len(missed):
                pb = self.plans.motion.at(recent[-1])[..., :3]
                stl = gossip_mod.steady_links(pr, pb, ar, self.channel, self.comm_m)[E, i, j]
                line.append(f"   rule at {at}: heard at {recent[-1]} {float(t_rx[E, i, j]) == recent[-1]} and steady link "
                            f"(prediction {recent[-1]} -> {at}) {bool(stl)}; comm_m {self.comm_m}, 0.8 comm_m {0.8 * self.comm_m:.0f}")
        kn = gossip_mod.key_of(hr[i, j]) % 2 == 1
        sn = gossip_mod.since_of(hr[i, j])
        mine_f = gossip_mod.key_of(gossip.rank[E, i]) % 2 == 1
        line.append(f"   guard (may_predict) {bool(guard[i, j])}; j's last message to {i} knew failed {[(int(x), int(sn[x])) for x in torch.nonzero(kn).flatten()]}; "
                    f"{i} knew before {[(int(x), int(gossip_mod.since_of(gossip.rank[E, i, x]))) for x in torch.nonzero(before[i]).flatten()]}")
        print("\n".join(line))
    _ = n
    return out


plan_mod.ServiceTargets.on_failures = on_failures
_compose_logged = service_mod.TeamPlans._compose


def compose(self, b, a, counts, failed, epoch, sources=None):  # noqa: ANN001, ANN202
    if b == E:
        pts, slot = self._plan_at(b, a, epoch, first=True)
        live = np.flatnonzero(slot >= 0)
        p0 = {int(i): pts[slot[i]] for i in live}
        d = {(i, j): float(np.hypot(*(p0[i] - p0[j]))) for i in p0 for j in p0 if i < j}
        print(f"P0 copy {a} epoch {epoch} F {np.flatnonzero(failed).tolist()}: " + " ".join(f"{i}{_fmt(p)}" for i, p in p0.items())
              + f"; R_link {self.grid.link_m:.1f}; pair distances " + " ".join(f"{i}-{j}:{x:.0f}" for (i, j), x in d.items()))
    out = _compose_logged(self, b, a, counts, failed, epoch, sources)
    if b == E and out is not None:
        print(f"PLAN copy {a} epoch {epoch}: survivors {np.flatnonzero(~failed).tolist()} points " + " ".join(_fmt(p) for p in out[0]))
    return out


service_mod.TeamPlans._compose = compose

mission = load_mission(a.mission).with_tup(a.tup)
twin_seed = suite_twin_seed(a.seed, a.variant)
loaded = {"pl-marl": load_policy("policies/pl-marl")} if a.controller == "pl-marl" else {}
make = (lambda env: ServiceController(env.mission)) if a.controller == "service" else controller_factory(a.controller, loaded)
env = CoverageEnv(mission, a.episodes, twin_seed)
ctl = make(env)
ctl.reset()
_run_sig = env.run_signalling
_receive = env.gossip.receive
HEARD: dict[int, np.ndarray] = {}


def run_signalling() -> None:
    POS[env.t] = env.pos[E].double().numpy().copy()
    ALIVE[env.t] = env.alive[E].numpy().copy()
    _run_sig()


def receive(got):  # noqa: ANN001, ANN202
    HEARD[env.t] = got[E].numpy().copy()
    _receive(got)


env.run_signalling = run_signalling
env.gossip.receive = receive
obs = env.observe()
POS[obs.t] = env.pos[E].double().numpy().copy()
ALIVE[obs.t] = env.alive[E].numpy().copy()
cover = []
prev_k = None
print(f"# trace seed {a.seed} {a.mission} episode {E} T_up {a.tup} {a.controller} replan LR {a.local_repairs}")
with torch.inference_mode():
    while not env.done:
        obs, _, info = env.step(ctl.act(obs))
        t = obs.t
        POS[t] = env.pos[E].double().numpy().copy()
        ALIVE[t] = env.alive[E].numpy().copy()
        cover.append(info.coverage)
        g = env.gossip
        kn = g.failed[E].numpy()
        sn = g.since[E].numpy()
        k = [(i, [(int(j), int(sn[i, j])) for j in np.flatnonzero(kn[i])]) for i in range(env.n) if ALIVE[t][i]]
        if k != prev_k:
            print(f"KNOW t {t}: " + "; ".join(f"{i}:{x}" for i, x in k))
            prev_k = k
        for s in sorted(x for x in HEARD if x >= 50):
            rx = HEARD.pop(s)
            hear = "; ".join(f"{i}<-{np.flatnonzero(rx[i]).tolist()}" for i in range(env.n) if ALIVE[s][i])
            print(f"HEARD t {s}: alive {np.flatnonzero(ALIVE[s]).tolist()}; {hear}; pos " +
                  " ".join(f"{i}{_fmt(POS[s][i])}" for i in np.flatnonzero(ALIVE[s])))
        HEARD.clear()
trace = torch.cat(cover, -1).numpy()
after = trace[E, dec.FAIL_S - 1 + 30:].mean()
print(f"RESULT episode {E}: mean C(t) from 30 s after the failure {after:.4f}; all episodes {trace[:, dec.FAIL_S - 1 + 30:].mean(1).round(4).tolist()}")
fe = (env.gossip.failed & env.alive.unsqueeze(-1) & env.alive.unsqueeze(1))[E]
print(f"END: live declared failed (copy, teammate): {torch.nonzero(fe).tolist()}")
print("COVER " + " ".join(f"{s}:{c:.3f}" for s, c in enumerate(trace[E].tolist(), 1) if s >= 90 and s % 10 == 0))
