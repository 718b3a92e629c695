"""Session 26 (issue 24): per-episode runner for the heard-link declaration (HL,
model/gossip.py::HEARD_LINK_MARGIN_DB = 3 dB), adapted from session 25's H-steady25 runner
(docs/results/issue24/session25/steady/runner.py) before any number was read: variants base / hl,
and `undeclared_end` (dead UAVs some live copy does not hold failed at the end).

Session 25's description follows.

For each suite failure family (missions/suite/suite.yaml) and T_up, and each variant (base: switch off;
ops: switch on), flies the family's episodes exactly as `plmarl suite --seed S --episodes E` does
(learning/eval/suite.py: mission variant v runs episodes_per_mission(E, len(missions))[v] episodes in
one twin batch seeded suite_twin_seed(S, v, 0), CoverageEnv(..., track_lambda2=True,
failure_prob=family's)), the same loop as twin/rollout.py::rollout, and records per episode:

* after50: mean C(t) for t > 50 s (`plmarl suite`'s coverage, run_method's from_s = 50);
* after_fail30: mean C(t) from 30 s after the failure (t >= fail_s + 30; decompose.py's `after`);
* false_end: (live knower, live identity) pairs declared failed at the end (decompose.py's false_end);
* false_max: the largest such count at any decision (decompose.py's false_max);
* false_ids: distinct live identities declared failed by some live copy at some decision, each
  counted once per episode (the primary count of criterion 1: a live UAV declared failed);
* false_pairs_new: (knower, identity) pairs newly declared while both were alive, over the episode;
* diagnostics (added after the pl-marl judgement run had started; they change no criterion): dead_end,
  dead_declared (dead UAVs some live copy declared), detect_s (mean delay of each one's first declaration).

`greedy` (T_up-independent) runs once per family (T_up of the family's first).

    PYTHONPATH=. python docs/results/issue24/session25/steady/runner.py --seeds 27 28 --episodes 30 \
        --controllers pl-marl --variants base ops > OUT.json 2> OUT.log
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
from plmarl_sitl.model import gossip as gossip_mod
from plmarl_sitl.twin.env import CoverageEnv

FAMILIES = ["failure_2of6", "failure_transit", "failure_split", "diffuse_failure", "failure"]

# --attribute (a diagnostic added after the judgement numbers): which rule made each new declaration.
# The twin's on_failures calls suspects (once per missed instant; DECLARE_AFTER_MISSED = 1) and steady,
# then gossip.declare(suspects | steady); the wrappers keep the last outputs and the declare wrapper books
# each new (knower, identity) declaration by rule (clear hearing, or steady alone) and by truth.
ATTR = {"on": False, "sus": None, "st": None, "alive": None, "counts": None}


def _attribute() -> None:
    from plmarl_sitl.learning.nn import plan as plan_mod
    from plmarl_sitl.model.gossip import Gossip

    sus0, st0, decl0 = plan_mod.suspects, plan_mod.steady, Gossip.declare

    def sus(*a, **k):  # noqa: ANN002, ANN003, ANN202
        ATTR["sus"] = sus0(*a, **k)
        return ATTR["sus"]

    def st(*a, **k):  # noqa: ANN002, ANN003, ANN202
        ATTR["st"] = st0(*a, **k)
        return ATTR["st"]

    def decl(self, failed, epoch):  # noqa: ANN001, ANN202
        c, alive = ATTR["counts"], ATTR["alive"]
        if c is not None and alive is not None:
            new = failed & ~self.failed & alive.unsqueeze(-1)
            s_ = ATTR["sus"] if ATTR["sus"] is not None else torch.zeros_like(new)
            t_ = ATTR["st"] if ATTR["st"] is not None else torch.zeros_like(new)
            live_j = alive.unsqueeze(1).expand_as(new)
            for name, m in (("false_new_clear", new & live_j & s_), ("false_new_steady_only", new & live_j & t_ & ~s_),
                            ("true_new_clear", new & ~live_j & s_), ("true_new_steady_only", new & ~live_j & t_ & ~s_)):
                c[name] += m.sum((-1, -2)).numpy()
        ATTR["sus"] = ATTR["st"] = None
        return decl0(self, failed, epoch)

    plan_mod.suspects, plan_mod.steady, Gossip.declare = sus, st, decl


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
    names = ("false_new_clear", "false_new_steady_only", "true_new_clear", "true_new_steady_only")
    ATTR["counts"] = {k: np.zeros(episodes, int) for k in names} if ATTR["on"] else None
    with torch.inference_mode():
        while not env.done:
            ATTR["alive"] = env.alive
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
            **({k: v.tolist() for k, v in ATTR["counts"].items()} if ATTR["counts"] is not None else {}),
            "undeclared_end": (((~g.failed) & alive.unsqueeze(-1)).any(1) & ~alive).sum(-1).tolist() if g is not None else [0] * episodes,
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
    ap.add_argument("--variants", nargs="+", default=["base", "hl"], choices=["base", "hl"])
    ap.add_argument("--greedy", action="store_true", help="also greedy, once per family")
    ap.add_argument("--suite", default="missions/suite/suite.yaml")
    ap.add_argument("--attribute", action="store_true", help="diagnostic: book each new declaration by rule and truth")
    a = ap.parse_args()
    if a.attribute:
        ATTR["on"] = True
        _attribute()
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
                gossip_mod.HEARD_LINK_MARGIN_DB = 3.0 if v == "hl" else None
                make = controller_factory(c, loaded)
                for vi, (m, e) in enumerate(zip(fam.missions, counts, strict=True)):
                    if e == 0:
                        continue
                    t0 = time.time()
                    r = fly(m.with_tup(tup), make, e, suite_twin_seed(seed, vi, 0), fam.spec.failure_prob, fail_s)
                    rows.append({"seed": seed, "family": name, "mission_variant": vi, "tup": tup, "controller": c,
                                 "variant": v, "fail_s": fail_s, **r})
                    print(f"seed {seed} {name} v{vi} T_up {tup} {c} {v}: after50 {np.mean(r['after50']):.4f} "
                          f"after_fail30 {np.mean(r['after_fail30']):.4f} false_ids {sum(r['false_ids'])} "
                          f"false_end {sum(r['false_end'])} undeclared {sum(r['undeclared_end'])} false_max {sum(r['false_max'])} ({time.time() - t0:.0f} s)",
                          file=sys.stderr, flush=True)
    gossip_mod.HEARD_LINK_MARGIN_DB = None
    print(json.dumps({"episodes": a.episodes, "rows": rows}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
