"""Issue 24, session 24, H-local24: compose/decompose.py plus --local-repairs (service.LOCAL_REPAIRS on
top of COMPOSE_REPAIRS: each repair moves only the failed UAV's neighbours in P0); each row then also logs
per episode the movers of all its composed repairs (cr_movers) and the fall-backs for want of a live
neighbour (lr_nonbr); --cr-log lines name each repair's allowed rows and movers.

H-compose24: session 24's fail/decompose.py plus --compose-repairs
(service.COMPOSE_REPAIRS, composable repairs); each row then logs, per episode, the copies' failure
re-plan steps that took the composable repairs (cr_steps), how many of them fell back to the full
re-solve (cr_fallback) and the repairs composed (cr_repairs); --cr-log FILE writes one line per step.

Session 24 (session 23's script plus --split-gate, service.SPLIT_GATE: the fewest-movers
choice only where the full re-solve is split-prone; each row then logs, per episode, the copies'
failure re-plan steps that reached the gate and how many it fired on). Session 23 added --movers, the fewest-movers re-plan of
model/service.py, FEWEST_MOVERS; the session 21/22 switches it still sets exist only at their tags): where the T_up 50 loss after a 2-of-6 failure goes, per controller,
on the same episodes (twin only; tuning seeds only).

Ways (every one flies the same episodes of bench.replan's seeds, suite_twin_seed(S, variant)):
* `replan`: the product (service or pl-marl as `plmarl suite` flies them).
* `spread` (a bound, not realisable): before every decision every survivor's knowledge is the
  merge of every survivor's (a zero-latency flood that ignores the heard graph): no hop, no
  split; detection as the product's.
* `instant` (bench.replan's ceiling): every survivor knows the true failed set at once.
* `phased`: the product with `signalling.phased` (each UAV broadcasts at its own phase).
And the greedy Oracle (`greedy`), true states every decision.

Per episode: mean C(t) from 30 s after the failure; the second every survivor knows every
failure (never: NaN); whether the survivors' heard graph (i hears j at j's instant) is split
(not strongly connected) at some signalling instant after the failure; live UAVs declared at
the end.

    PYTHONPATH=. python docs/results/issue24/session21/fail/decompose.py --seeds 7 8 --episodes 10 --tup 50 \
        --controllers service pl-marl --ways replan spread instant phased > decompose_s7_8.json
"""
from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
import torch

from plmarl_sitl.bench.replan import AFTER_S, greedy_after
from plmarl_sitl.learning.eval.controllers import ServiceController
from plmarl_sitl.learning.eval.evaluate import controller_factory
from plmarl_sitl.learning.nn import plan as plan_mod
from plmarl_sitl.learning.nn.io import load_policy
from plmarl_sitl.learning.train.seeds import suite_twin_seed
from plmarl_sitl.mission import load_mission
from plmarl_sitl.model import service as service_mod
from plmarl_sitl.model.graph import link_mask
from plmarl_sitl.twin.env import CoverageEnv

MISSIONS = ["missions/suite/failure_2of6_a.yaml", "missions/suite/failure_2of6_b.yaml"]
FAIL_S = 100


def strongly_connected(rx: torch.Tensor, alive: torch.Tensor) -> torch.Tensor:
    """(B,) the directed graph rx (B, N, N) [i, j] (i hears j) among alive (B, N) is strongly connected."""
    n = rx.shape[-1]
    a = (rx & alive.unsqueeze(-1) & alive.unsqueeze(-2)) | torch.eye(n, dtype=torch.bool)
    r = a.clone()
    for _ in range(n):
        r = r | ((r.float() @ a.float()) > 0)
    live = alive.unsqueeze(-1) & alive.unsqueeze(-2)
    return (r | ~live).all(-1).all(-1)


GATE = {"steps": None, "fired": None}  # per episode of the running row: gate decisions, and how many were split-prone
_fewest = service_mod.TeamPlans._fewest_movers


def _logged(self, b, a, counts, alive, src):  # noqa: ANN001, ANN202
    """TeamPlans._fewest_movers, counting the split gate's decisions per episode b (None: no old plan)."""
    out = _fewest(self, b, a, counts, alive, src)
    if out is not None and GATE["steps"] is not None:
        GATE["steps"][b] += 1
        GATE["fired"][b] += int(out[2])
    return out


service_mod.TeamPlans._fewest_movers = _logged

CR = {"steps": None, "fallback": None, "repairs": None, "movers": None, "nonbr": None, "log": None, "row": ""}
_compose = service_mod.TeamPlans._compose


def _cr_logged(self, b, a, counts, failed, epoch, sources=None):  # noqa: ANN001, ANN202
    """TeamPlans._compose, counting its steps and fall-backs per episode b."""
    out = _compose(self, b, a, counts, failed, epoch, sources)
    if CR["steps"] is not None:
        CR["steps"][b] += 1
        CR["fallback"][b] += int(out is None)
        CR["repairs"][b] += 0 if out is None else int(np.sum(failed))
        log = self.repair_log
        CR["movers"][b] += 0 if out is None else sum(len(x[2]) for x in log if len(x) == 3)
        CR["nonbr"][b] += int(out is None and bool(log) and log[-1][1] == "no neighbour")
        if CR["log"] is not None:
            detail = "; ".join(f"{x[0]}: {x[1]}" if len(x) == 2 else f"{x[0]}: allowed {x[1]} movers {x[2]}" for x in log)
            print(f"{CR['row']} ep {b} copy {a} epoch {epoch} F {np.flatnonzero(failed).tolist()} "
                  f"{'fell back' if out is None else f'composed {int(np.sum(failed))} repairs'} [{detail}]", file=CR["log"])
    return out


service_mod.TeamPlans._compose = _cr_logged


def run(mission, make, episodes: int, seed: int, way: str) -> dict:  # noqa: ANN001
    fail_s = FAIL_S
    GATE["steps"], GATE["fired"] = np.zeros(episodes, int), np.zeros(episodes, int)
    CR["steps"], CR["fallback"], CR["repairs"], CR["movers"], CR["nonbr"] = (np.zeros(episodes, int) for _ in range(5))
    if way == "phased":
        mission = mission.with_phased()
    env = CoverageEnv(mission, episodes, seed)
    ctl = make(env)
    ctl.reset()
    obs = env.observe()
    cover = []
    all_known = np.full(episodes, np.nan)
    split = np.zeros(episodes, bool)
    false_any = np.zeros(episodes, int)
    with torch.inference_mode():
        while not env.done:
            g = env.gossip
            dead = ~env.alive
            if way == "instant" and bool(dead.any()):
                new = dead.unsqueeze(1).expand(-1, env.n, -1) & env.alive.unsqueeze(-1) & ~g.failed
                if bool(new.any()):
                    g.declare(new, torch.where(new.any(-1), torch.full_like(g.epoch, obs.t), torch.zeros_like(g.epoch)))
            if way == "spread" and bool(dead.any()):
                live = env.alive.unsqueeze(-1)
                merged = torch.where(live, g.rank, torch.zeros_like(g.rank)).amax(1, keepdim=True)
                g.rank = torch.where(live, torch.maximum(g.rank, merged), g.rank)
            obs, _, info = env.step(ctl.act(obs))
            cover.append(info.coverage)
            if obs.t > fail_s and env.events.instant_tup(obs.t) and bool(dead.any()):
                # the heard graph at the instants after the failure (every second for phased: each sender at its own)
                tup = env.events.instant_tup(obs.t)
                if obs.t % tup < mission.timing.decision_every_s:
                    rx, _ = link_mask(env.pos, env.alive, mission.channel, mission.radii.comm_m)
                    split |= ~strongly_connected(rx, env.alive).numpy()
            alive = env.alive
            fa = (env.gossip.failed & alive.unsqueeze(-1) & alive.unsqueeze(1)).sum((-1, -2)).numpy()
            false_any = np.maximum(false_any, fa)
            known = env.gossip.failed & (~alive).unsqueeze(1)
            every = ((known == (~alive).unsqueeze(1)).all(-1) | ~alive).all(-1).numpy() & (~alive).any(-1).numpy()
            all_known[np.isnan(all_known) & every] = obs.t
    trace = torch.cat(cover, -1).numpy()
    level = trace[:, fail_s - 1 + AFTER_S:].mean(1)
    failed = env.gossip.failed & env.alive.unsqueeze(-1) & env.alive.unsqueeze(1)
    return {"after": level.tolist(), "all_know_s": (all_known - fail_s).tolist(), "split": split.tolist(),
            "false_end": failed.sum((-1, -2)).tolist(), "false_max": false_any.tolist(), "trace_mean": trace.mean(0).tolist(),
            "gate_steps": GATE["steps"].tolist(), "gate_fired": GATE["fired"].tolist(),
            "cr_steps": CR["steps"].tolist(), "cr_fallback": CR["fallback"].tolist(), "cr_repairs": CR["repairs"].tolist(),
            "cr_movers": CR["movers"].tolist(), "lr_nonbr": CR["nonbr"].tolist()}


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="+", default=[7, 8])
    ap.add_argument("--episodes", type=int, default=10)
    ap.add_argument("--tup", type=int, nargs="+", default=[50])
    ap.add_argument("--controllers", nargs="+", default=["service", "pl-marl"])
    ap.add_argument("--ways", nargs="+", default=["replan", "spread", "instant", "phased"])
    ap.add_argument("--missions", nargs="+", default=MISSIONS)
    ap.add_argument("--variants", type=int, nargs="+", help="each mission's suite variant index (default: its position; b alone is 1)")
    ap.add_argument("--policies", default="policies")
    ap.add_argument("--guard-lag-s", type=int, default=0, help="may_predict relaxed for declarations this old (0: off)")
    ap.add_argument("--hold", action="store_true", help="HOLD_UNTIL_TOLD: a knower keeps its point until it has told")
    ap.add_argument("--leash", action="store_true", help="HOLD_UNTIL_TOLD in HOLD_MODE leash")
    ap.add_argument("--rejoin", action="store_true", help="REJOIN: an agent that heard nobody at the newest instant flies back into range")
    ap.add_argument("--alone", action="store_true", help="HOLD_ALONE: hold/leash only an agent its new point would cut off")
    ap.add_argument("--pre-replan", action="store_true", help="session 22: DECLARE_PRE_REPLAN (test a guarded silent teammate at its pre-re-plan positions too)")
    ap.add_argument("--pre-replan-missed", type=int, default=2, help="PRE_REPLAN_MISSED (session 22: first run used 1)")
    ap.add_argument("--pre-replan-seen", action="store_true", help="PRE_REPLAN_SEEN: own position and heard states at the newest instant")
    ap.add_argument("--pin", action="store_true", help="session 22: PIN_UNAWARE (re-plan with unaware heard teammates pinned)")
    ap.add_argument("--pin-quiet", action="store_true", help="PIN_QUIET: a copy holding pins declares nobody")
    ap.add_argument("--phased-epoch", default="period", choices=["instant", "period"])
    ap.add_argument("--movers", action="store_true", help="session 23: service.FEWEST_MOVERS (re-plan moving as few survivors as it needs)")
    ap.add_argument("--movers-k", type=int, default=2, help="service.MOVERS_K")
    ap.add_argument("--movers-margin", type=float, default=1.0, help="service.MOVERS_MARGIN (users)")
    ap.add_argument("--movers-frac", type=float, default=0.0, help="service.MOVERS_MARGIN_FRAC (of the map's users)")
    ap.add_argument("--split-gate", action="store_true", help="session 24: service.SPLIT_GATE (fewest movers, margin --movers-frac, only where split-prone)")
    ap.add_argument("--compose-repairs", action="store_true", help="H-compose24: service.COMPOSE_REPAIRS (composable repairs)")
    ap.add_argument("--local-repairs", action="store_true", help="H-local24: service.LOCAL_REPAIRS (with COMPOSE_REPAIRS): only the failed UAV's neighbours move")
    ap.add_argument("--cr-log", help="a file: one line per composable-repairs step")
    ap.add_argument("--fail-s", type=int, default=100, help="the missions' failure second (the window starts 30 s later)")
    a = ap.parse_args()
    global FAIL_S
    FAIL_S = a.fail_s
    service_mod.FEWEST_MOVERS = a.movers
    service_mod.SPLIT_GATE = a.split_gate
    service_mod.COMPOSE_REPAIRS = a.compose_repairs or a.local_repairs
    service_mod.LOCAL_REPAIRS = a.local_repairs
    CR["log"] = open(a.cr_log, "w") if a.cr_log else None
    service_mod.MOVERS_K = a.movers_k
    service_mod.MOVERS_MARGIN = a.movers_margin
    service_mod.MOVERS_MARGIN_FRAC = a.movers_frac
    plan_mod.DECLARE_PRE_REPLAN = a.pre_replan
    plan_mod.PRE_REPLAN_MISSED = a.pre_replan_missed
    plan_mod.PRE_REPLAN_SEEN = a.pre_replan_seen
    plan_mod.PIN_UNAWARE = a.pin
    plan_mod.PIN_QUIET = a.pin_quiet
    plan_mod.PHASED_EPOCH = a.phased_epoch
    plan_mod.GUARD_LAG_S = a.guard_lag_s
    plan_mod.REJOIN = a.rejoin
    plan_mod.HOLD_ALONE = a.alone
    plan_mod.HOLD_UNTIL_TOLD = a.hold or a.leash
    plan_mod.HOLD_MODE = "leash" if a.leash else "hold"
    loaded = {"pl-marl": load_policy(f"{a.policies}/pl-marl")} if "pl-marl" in a.controllers else {}
    rows = []
    for seed in a.seeds:
        for v, path in enumerate(a.missions):
            base = load_mission(path)
            twin_seed = suite_twin_seed(seed, a.variants[v] if a.variants else v)
            for tup in a.tup:
                m = base.with_tup(tup)
                g = greedy_after(m, a.episodes, twin_seed, a.fail_s, 0.0)
                rows.append({"seed": seed, "mission": path, "tup": tup, "controller": "greedy", "way": "-", "after": g.tolist()})
                for c in a.controllers:
                    make = (lambda env: ServiceController(env.mission)) if c == "service" else controller_factory(c, loaded)
                    for way in a.ways:
                        t0 = time.time()
                        CR["row"] = f"seed {seed} {path[-6:]} T_up {tup} {c} {way}"
                        r = run(m, make, a.episodes, twin_seed, way)
                        rows.append({"seed": seed, "mission": path, "tup": tup, "controller": c, "way": way, **r})
                        print(f"seed {seed} {path[-6:]} T_up {tup} {c} {way}: after {np.mean(r['after']):.4f} "
                              f"of greedy {np.mean(r['after']) / g.mean():.4f} never {int(np.isnan(r['all_know_s']).sum())} "
                              f"split {int(np.sum(r['split']))} gate {int(np.sum(r['gate_fired']))}/{int(np.sum(r['gate_steps']))} cr {int(np.sum(r['cr_steps']))} fb {int(np.sum(r['cr_fallback']))} rep {int(np.sum(r['cr_repairs']))} mov {int(np.sum(r['cr_movers']))} nonbr {int(np.sum(r['lr_nonbr']))} false_end {int(np.sum(r['false_end']))} false_max {int(np.sum(r['false_max']))} ({time.time() - t0:.0f} s)",
                              file=sys.stderr, flush=True)
    print(json.dumps({"episodes": a.episodes, "movers": a.movers, "movers_k": a.movers_k, "movers_margin": a.movers_margin, "movers_frac": a.movers_frac, "split_gate": a.split_gate, "compose_repairs": a.compose_repairs or a.local_repairs, "local_repairs": a.local_repairs, "pre_replan": a.pre_replan, "pre_replan_missed": a.pre_replan_missed, "pre_replan_seen": a.pre_replan_seen, "pin": a.pin, "pin_quiet": a.pin_quiet, "guard_lag_s": a.guard_lag_s, "hold": a.hold, "leash": a.leash, "rejoin": a.rejoin, "alone": a.alone, "phased_epoch": a.phased_epoch, "rows": rows}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
