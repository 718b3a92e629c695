"""H-hold26 (issue 24): per-episode runner for HOLD (a declaration that allows for a teammate's local
repair, `learning/nn/plan.py::HOLD_FOR_REPAIRS`), adapted from session 25's
docs/results/issue24/session25/steady/runner.py before any number was read.

Variants (controller `pl-marl`): base = `pl-marl` (failure_replan: resolve, the default); lr =
`pl-marl-local-repairs`; lr_hold = `pl-marl-local-repairs` with HOLD_FOR_REPAIRS on. Same episodes for all
(`plmarl suite`'s: mission variant v runs episodes_per_mission(E, len(missions))[v] episodes in one twin
batch seeded suite_twin_seed(S, v, 0), CoverageEnv(..., track_lambda2=True, failure_prob=family's)), the
loop of twin/rollout.py::rollout; per episode: after50 (mean C(t), t > 50 s), after_fail30 (t >= fail_s + 30),
false_end, false_max, false_ids (distinct live identities declared failed by some live copy over the
episode), false_pairs_new, dead_end, dead_declared, detect_s (mean delay of each dead UAV's first
declaration by a live copy), and held_live / held_dead: (copy, suspect) pairs HOLD kept undeclared at a
decision, the suspect alive / dead then (0 for base and lr). `greedy` runs once per family.

    PYTHONPATH=. python docs/results/issue24/session26/hold/runner.py --seeds 29 30 --episodes 30 \
        --tups 50 --variants base lr lr_hold --greedy > OUT.json 2> OUT.log
"""
from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np
import torch

from plmarl_sitl.learning.eval.evaluate import controller_factory
from plmarl_sitl.learning.eval.suite import BATCH, FAILURE_AT_S, episodes_per_mission, family_tups, load_suite
from plmarl_sitl.learning.nn.io import load_policy
from plmarl_sitl.learning.train.seeds import suite_twin_seed
from plmarl_sitl.learning.nn import plan as plan_mod
from plmarl_sitl.twin.env import CoverageEnv

FAMILIES = ["failure_2of6", "failure_transit", "failure_split", "diffuse_failure", "failure"]

VARIANTS = {"base": ("pl-marl", False), "lr": ("pl-marl-local-repairs", False), "lr_hold": ("pl-marl-local-repairs", True)}
HELD = {"alive": None, "live": None, "dead": None}


def _count_held() -> None:
    """Wrap plan.held_for_repairs (on_failures looks it up at each call) to book the held pairs by truth."""
    h0 = plan_mod.held_for_repairs

    def held(*a, **k):  # noqa: ANN002, ANN003, ANN202
        out = h0(*a, **k)
        alive = HELD["alive"]
        if alive is not None and HELD["live"] is not None:
            m = out & alive.unsqueeze(-1)  # held by a live copy
            HELD["live"] += (m & alive.unsqueeze(1)).sum((-1, -2)).numpy()
            HELD["dead"] += (m & ~alive.unsqueeze(1)).sum((-1, -2)).numpy()
        return out

    plan_mod.held_for_repairs = held


def fly(mission, make, episodes: int, seed: int, failure_prob: float, fail_s: int) -> dict:  # noqa: ANN001
    assert episodes <= BATCH
    env = CoverageEnv(mission, episodes, seed, track_lambda2=True, failure_prob=failure_prob)
    ctl = make(env)
    ctl.reset()
    obs = env.observe()
    cover = []
    false_max = np.zeros(episodes, int)
    ids_ever = torch.zeros(episodes, env.n, dtype=torch.bool)
    pairs_new = np.zeros(episodes, int)
    prev = torch.zeros(episodes, env.n, env.n, dtype=torch.bool)
    first_decl = torch.full((episodes, env.n), float("nan"), dtype=torch.float64)  # first declaration of a dead UAV
    HELD["live"], HELD["dead"] = np.zeros(episodes, int), np.zeros(episodes, int)
    with torch.inference_mode():
        while not env.done:
            HELD["alive"] = env.alive
            obs, _, info = env.step(ctl.act(obs))
            cover.append(info.coverage)
            g = env.gossip
            if g is None:
                continue
            alive = env.alive
            live_pair = alive.unsqueeze(-1) & alive.unsqueeze(1)
            fd = g.failed & live_pair & ~torch.eye(env.n, dtype=torch.bool)
            false_max = np.maximum(false_max, fd.sum((-1, -2)).numpy())
            ids_ever |= fd.any(1)
            pairs_new += (fd & ~prev).sum((-1, -2)).numpy()
            prev = fd
            dead_decl = (g.failed & alive.unsqueeze(-1)).any(1) & ~alive
            first_decl = torch.where(dead_decl & first_decl.isnan(), torch.full_like(first_decl, float(obs.t)), first_decl)
    trace = torch.cat(cover, -1).numpy()
    alive = env.alive
    g = env.gossip
    fe = np.zeros(episodes, int) if g is None else (g.failed & alive.unsqueeze(-1) & alive.unsqueeze(1)
                                                   & ~torch.eye(env.n, dtype=torch.bool)).sum((-1, -2)).numpy()
    return {"after50": trace[:, 50:].mean(1).tolist(), "after_fail30": trace[:, fail_s - 1 + 30:].mean(1).tolist(),
            "false_end": fe.tolist(), "false_max": false_max.tolist(), "false_ids": ids_ever.sum(-1).tolist(),
            "false_pairs_new": pairs_new.tolist(),
            # diagnostics: dead UAVs at the end, how many some live copy ever declared, and the mean
            # delay (s) of the first declaration of each after fail_s (NaN: none declared)
            "held_live": HELD["live"].tolist(), "held_dead": HELD["dead"].tolist(),
            "dead_end": (~alive).sum(-1).tolist(), "dead_declared": (~first_decl.isnan()).sum(-1).tolist(),
            "detect_s": [float(np.nanmean(x)) if np.isfinite(x).any() else float("nan")
                         for x in (first_decl - fail_s).numpy()]}


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="+", required=True)
    ap.add_argument("--episodes", type=int, default=30)
    ap.add_argument("--families", nargs="+", default=FAMILIES)
    ap.add_argument("--tups", type=int, nargs="+", default=[15, 50])
    ap.add_argument("--controllers", nargs="+", default=["pl-marl"])
    ap.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    ap.add_argument("--greedy", action="store_true", help="also greedy, once per family")
    ap.add_argument("--suite", default="missions/suite/suite.yaml")
    a = ap.parse_args()
    _count_held()
    _, fams = load_suite(a.suite)
    loaded = {"pl-marl": load_policy("policies/pl-marl")} if "pl-marl" in a.controllers else {}
    rows = []
    for seed in a.seeds:
        for name in a.families:
            fam = fams[name]
            fail_s = int(fam.spec.failure_at_s or FAILURE_AT_S)
            counts = episodes_per_mission(a.episodes, len(fam.missions))
            tups = family_tups(fam, a.tups)
            jobs = [("greedy", "-", tups[0])] if a.greedy else []
            jobs += [(c, v, t) for t in tups for c in a.controllers for v in a.variants]
            for c, v, tup in jobs:
                method, hold = (c, False) if c == "greedy" else VARIANTS[v]
                if c != "greedy":
                    assert c == "pl-marl", c
                plan_mod.HOLD_FOR_REPAIRS = hold
                make = controller_factory(method, loaded)
                for vi, (m, e) in enumerate(zip(fam.missions, counts, strict=True)):
                    if e == 0:
                        continue
                    t0 = time.time()
                    r = fly(m.with_tup(tup), make, e, suite_twin_seed(seed, vi, 0), fam.spec.failure_prob, fail_s)
                    rows.append({"seed": seed, "family": name, "mission_variant": vi, "tup": tup, "controller": c,
                                 "variant": v, "method": method, "hold": hold, "fail_s": fail_s, **r})
                    print(f"seed {seed} {name} v{vi} T_up {tup} {c} {v}: after50 {np.mean(r['after50']):.4f} "
                          f"after_fail30 {np.mean(r['after_fail30']):.4f} false_ids {sum(r['false_ids'])} "
                          f"false_end {sum(r['false_end'])} held live/dead {sum(r['held_live'])}/{sum(r['held_dead'])} "
                          f"({time.time() - t0:.0f} s)",
                          file=sys.stderr, flush=True)
    plan_mod.HOLD_FOR_REPAIRS = False
    print(json.dumps({"episodes": a.episodes, "rows": rows}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
