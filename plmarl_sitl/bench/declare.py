"""False failure declarations, measured in the twin (issue 24, session 13).

A silent teammate is declared failed after `DECLARE_AFTER_MISSED` missed signalling
instants at which the plan-aware prediction put it in clear hearing (model/gossip.py). A
false declaration lasts until the UAV is heard again (schema 4), so this counts them over many
episodes of missions without failures, and with the link losses the missions carry
(link blackouts, broker outages, GNSS noise) and those the controller's own flight
causes (a learnt policy does not fly the plan exactly).

Per mission, T_up and controller: the episodes with any live UAV declared failed, the
declared (receiver, live teammate) pairs at the end, and the raw evidence behind them:
the (receiver, live teammate, instant) triples the prediction put in clear hearing
(`suspects` on a live pair: the tests a declaration rule makes) and how many of those were
missed. One missed instant in clear hearing is what the rule declares on; its rate is the
false-alarm probability per test. Seeds are from the evaluation range.

    python -m plmarl_sitl.bench.declare missions/paper_urban.yaml missions/blackout.yaml --tup 15 50 --episodes 20 --seed 5
"""

from __future__ import annotations

import argparse
import json
import sys

import torch

from plmarl_sitl.errors import run_reporting
from plmarl_sitl.learning.eval.controllers import LearnedController, ServiceController
from plmarl_sitl.learning.train.seeds import suite_twin_seed
from plmarl_sitl.mission import Mission, load_mission
from plmarl_sitl.model.gossip import DECLARE_AFTER_MISSED, steady, suspects
from plmarl_sitl.model.gossip import heard as heard_link
from plmarl_sitl.twin.env import CoverageEnv

PROG = "python -m plmarl_sitl.bench.declare"


def controller(method: str, mission: Mission, declare_after: int = DECLARE_AFTER_MISSED):  # noqa: ANN201 - a twin controller
    if method == "service":
        return ServiceController(mission, declare_after=declare_after)
    from plmarl_sitl.learning.nn.io import load_policy  # torch policies only when asked for

    lp = load_policy(method, mission)
    ctl = LearnedController(lp.tracker, lp.policy, mission)
    if ctl.perceive.plan is not None:
        ctl.perceive.plan.declare_after = declare_after
    return ctl


def plans_of(ctl):  # noqa: ANN001, ANN201
    t = ctl.targets if isinstance(ctl, ServiceController) else ctl.perceive.plan
    return t.plans, t


def count(obs, env: CoverageEnv, plans, t: int, prev: int | None, mission: Mission, tally: dict) -> None:  # noqa: ANN001
    """Add the live pairs predicted in clear hearing at instant t and those of them missed,
    and the same for the steady links and the links predicted clear enough (`heard`; both
    heard at the previous instant `prev`)."""
    n = env.n
    pred = plans.motion.at(t)[..., :3]
    own = pred[:, torch.arange(n), torch.arange(n)]
    live = env.alive.unsqueeze(-1) & env.alive.unsqueeze(-2) & ~torch.eye(n, dtype=torch.bool)
    heard = (obs.nbr_t_rx == float(t)).any(-1, keepdim=True)  # receivers that heard someone (the rule's condition)
    comm = float(mission.radii.comm_m)
    clear = suspects(live & heard, pred, torch.arange(n), own, mission.channel, comm)
    miss = obs.nbr_t_rx < float(t)
    tally["clear_tests"] += int(clear.sum())
    tally["clear_missed"] += int((clear & miss).sum())
    if prev is not None:
        was = tally["rx_prev"] == float(prev)  # heard at the previous instant
        st = steady(live & heard & was, pred, plans.motion.at(prev)[..., :3], torch.arange(n), mission.channel, comm)
        tally["steady_tests"] += int(st.sum())
        tally["steady_missed"] += int((st & miss).sum())
        hl = heard_link(live & heard & was, pred, torch.arange(n), mission.channel, comm)
        tally["heard_tests"] += int(hl.sum())
        tally["heard_missed"] += int((hl & miss).sum())
    tally["rx_prev"] = obs.nbr_t_rx.clone()


def run(mission: Mission, method: str, episodes: int, seed: int, declare_after: int = DECLARE_AFTER_MISSED) -> dict:
    env = CoverageEnv(mission, episodes, seed)
    ctl = controller(method, mission, declare_after)
    ctl.reset()
    obs = env.observe()
    tally = {"clear_tests": 0, "clear_missed": 0, "steady_tests": 0, "steady_missed": 0, "heard_tests": 0, "heard_missed": 0,
             "rx_prev": None}
    prev = None
    with torch.inference_mode():
        while not env.done:
            accel = ctl.act(obs)  # advances the prediction to a decision second
            plans, targets = plans_of(ctl)
            k = targets.instants.last(obs.t) if plans is not None and plans.motion is not None else 0
            if k > 0 and k != prev and plans.motion.t == obs.t:  # the first decision after each instant
                count(obs, env, plans, k, prev, mission, tally)
                prev = k
            obs, _, _ = env.step(accel)
    alive = env.alive
    false = env.gossip.failed & alive.unsqueeze(-1) & alive.unsqueeze(-2)
    return {"episodes": episodes, "episodes_with_false": int(false.flatten(1).any(-1).sum()),
            "false_pairs": int(false.sum()), **{k: v for k, v in tally.items() if k != "rx_prev"}}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    ap.add_argument("missions", nargs="+")
    ap.add_argument("--tup", type=int, nargs="+", default=[15, 50])
    ap.add_argument("--methods", nargs="+", default=["service"], help="service, or a policy directory")
    ap.add_argument("--episodes", type=int, default=20)
    ap.add_argument("--seed", type=int, default=5, help="suite run seed (evaluation seeds)")
    ap.add_argument("--declare-after", type=int, default=DECLARE_AFTER_MISSED,
                    help="missed instants before a declaration (session 12's rule: 2)")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args(argv)

    def go() -> int:
        rows = []
        for v, path in enumerate(args.missions):
            base = load_mission(path)
            seed = suite_twin_seed(args.seed, v)
            for tup in args.tup:
                for method in args.methods:
                    r = run(base.with_tup(tup), method, args.episodes, seed, args.declare_after)
                    rows.append({"mission": path, "tup": tup, "method": method, "twin_seed": seed,
                                 "declare_after": args.declare_after, **r})
                    if not args.json:
                        print(rows[-1], flush=True)
        if args.json:
            print(json.dumps({"seed": args.seed, "rows": rows}))
        return 0

    return run_reporting(PROG, go)


if __name__ == "__main__":
    sys.exit(main())
