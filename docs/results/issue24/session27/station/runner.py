"""Session 27 (issue 24): per-episode runner for the heard-link declaration gated on station (HLS: prototype switch
`learning/nn/plan.py::HEARD_STATION_MPS` at tag s27-station-prototype). Variants: base (the heard-link rule off:
gossip.HEARD_MARGIN_DB = 200 dB, no link qualifies), hl (main's default), hls (hl only where both ends of the link
are predicted at most S m/s at the missed instant), lrs (hl, and a local repair only where every survivor is predicted
within --station-m of its first-plan point at the epoch, else the re-solve: `model/repairs.py::STATION_M`; it changes
only `pl-marl-local-repairs`). Flies each suite failure family's episodes exactly as
`plmarl suite --seed S --episodes E` does, with session 26's per-episode `fly`
(docs/results/issue24/session26/heard/runner.py: after50, after_fail30, false_ids, undeclared_end, ...).
--log: also record every firing of the heard-link rule alone (decision second, faster end's predicted speed,
whether the declared UAV was alive) and every local repair's largest survivor distance from its first-plan point.

    PYTHONPATH=. python docs/results/issue24/session27/station/runner.py --seeds 34 35 --tups 50 --variants base hl hls
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import sys
import time
from pathlib import Path

import numpy as np

from plmarl_sitl.learning.eval.evaluate import controller_factory
from plmarl_sitl.learning.eval.suite import FAILURE_AT_S, episodes_per_mission, family_tups, load_suite
from plmarl_sitl.learning.nn import plan as plan_mod
from plmarl_sitl.learning.nn.io import load_policy
from plmarl_sitl.learning.train.seeds import suite_twin_seed
from plmarl_sitl.model import gossip as gossip_mod
from plmarl_sitl.model import repairs as repairs_mod

_spec = importlib.util.spec_from_file_location("heard_runner", Path(__file__).parents[2] / "session26/heard/runner.py")
heard_runner = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(heard_runner)

FAMILIES = ["failure_2of6", "failure_transit", "failure_split", "diffuse_failure", "failure"]


def set_variant(v: str, station: float, station_m: float) -> None:
    gossip_mod.HEARD_MARGIN_DB = 200.0 if v == "base" else 3.0
    plan_mod.HEARD_STATION_MPS = station if v == "hls" else None
    repairs_mod.STATION_M = station_m if v == "lrs" else None


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="+", required=True)
    ap.add_argument("--episodes", type=int, default=30)
    ap.add_argument("--families", nargs="+", default=FAMILIES)
    ap.add_argument("--tups", type=int, nargs="+", default=[15, 50])
    ap.add_argument("--variants", nargs="+", default=["base", "hl", "hls"], choices=["base", "hl", "hls", "lrs"])
    ap.add_argument("--controllers", nargs="+", default=["pl-marl"])
    ap.add_argument("--station-m", type=float, default=50.0, help="lrs: m")
    ap.add_argument("--station", type=float, default=2.0, help="hls: m/s")
    ap.add_argument("--greedy", action="store_true")
    ap.add_argument("--log", action="store_true")
    a = ap.parse_args()
    _, fams = load_suite("missions/suite/suite.yaml")
    loaded = {"pl-marl": load_policy("policies/pl-marl")}  # the local-repairs method loads the same files
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
                set_variant(v, a.station, a.station_m)
                make = controller_factory(c, loaded)
                for vi, (m, e) in enumerate(zip(fam.missions, counts, strict=True)):
                    if e == 0:
                        continue
                    plan_mod.HEARD_LOG = [] if a.log else None
                    repairs_mod.STATION_LOG = [] if a.log else None
                    t0 = time.time()
                    r = heard_runner.fly(m.with_tup(tup), make, e, suite_twin_seed(seed, vi, 0), fam.spec.failure_prob, fail_s)
                    if a.log:
                        r["heard_log"], r["station_log"] = plan_mod.HEARD_LOG, repairs_mod.STATION_LOG
                    rows.append({"seed": seed, "family": name, "mission_variant": vi, "tup": tup, "controller": c,
                                 "variant": v, "fail_s": fail_s, **r})
                    print(f"seed {seed} {name} v{vi} T_up {tup} {c} {v}: after50 {np.mean(r['after50']):.4f} "
                          f"after_fail30 {np.mean(r['after_fail30']):.4f} false_ids {sum(r['false_ids'])} "
                          f"undeclared {sum(r['undeclared_end'])} ({time.time() - t0:.0f} s)", file=sys.stderr, flush=True)
    set_variant("hl", a.station, a.station_m)
    print(json.dumps({"episodes": a.episodes, "station": a.station, "rows": rows}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
