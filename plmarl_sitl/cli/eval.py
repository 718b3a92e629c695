"""`plmarl eval`: deterministic coverage sweeps over methods and T_up, with statistics and plots."""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

from plmarl_sitl.cmdline import add_seed, progress, tup_arg
from plmarl_sitl.config import PROJECT_POLICIES
from plmarl_sitl.errors import UserError
from plmarl_sitl.learning.eval.methods import methods_help, parse_methods

DEFAULT_METHODS = "pl-marl,gru,tag-mappo,dead-reckoning,service,greedy,clairvoyant"


def _methods(text: str) -> list[str]:
    try:
        return parse_methods(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _tups(text: str) -> list[int]:
    """'5,10,...,50' (an arithmetic range written with ...) or '5,15,50'."""
    parts = [p.strip() for p in text.split(",") if p.strip()]
    if "..." in parts:
        i = parts.index("...")
        if i < 2 or i != len(parts) - 2:
            raise argparse.ArgumentTypeError("write a range as A,B,...,Z (e.g. 5,10,...,50)")
        a, b, z = (tup_arg(parts[0]), tup_arg(parts[1]), tup_arg(parts[-1]))
        step = b - a
        if step <= 0 or (z - a) % step:
            raise argparse.ArgumentTypeError(f"{text!r}: not an increasing arithmetic range")
        return list(range(a, z + 1, step))
    return [tup_arg(p) for p in parts]


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "eval",
        help="evaluate trained policies and baselines in the digital twin",
        description="Run deterministic policies on the same episodes for every method and T_up. "
        "Coverage of an episode is the mean C(t) after --from-s seconds (steady state; the "
        "whole-episode mean is in the saved results); mean and 95% CI over episodes, lambda_2, "
        "and PL-MARL against each other method: the two-sided Mann-Whitney U p-value (unpaired), the two-sided "
        "Wilcoxon signed-rank p-value of the per-episode differences (paired: the same episodes) and the episodes "
        "it wins and loses. "
        "Fractions are of the best reference of each episode (the best of service, greedy and clairvoyant among "
        "the methods run; none is a proven bound) and the table names it.\n\nMethods: " + methods_help() + ". "
        "('oracle' is still accepted for greedy, for one release.)",
        epilog="example:\n  plmarl eval missions/paper_urban.yaml --methods pl-marl,service,greedy,clairvoyant "
        "--tup 5,10,...,50 --episodes 100 --seed 7 --out runs/eval --json",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("mission", help="mission YAML, e.g. missions/paper_urban.yaml")
    p.add_argument("--methods", type=_methods, default=_methods(DEFAULT_METHODS), help=f"comma list (default: {DEFAULT_METHODS})")
    p.add_argument("--tup", type=_tups, default=[5, 10, 15, 20, 25, 30, 35, 40, 45, 50], help="T_up values, e.g. 5,10,...,50 (default)")
    p.add_argument("--episodes", type=int, default=100, help="episodes per method and T_up (default: 100)")
    add_seed(p)
    p.add_argument("--policies", default=str(PROJECT_POLICIES),
                   help="directory holding <method>/{predictor.pt,policy.pt,card.yaml} (default: the project's policies/)")
    p.add_argument("--from-s", type=int, default=50, help="steady-state window starts after this many seconds (default: 50)")
    p.add_argument("--failure-prob", type=float, default=0.0, help="probability of one random node failing at t = 100 s")
    p.add_argument("--out", default=None, help="write results.json, results.md and PNG plots here")
    p.add_argument("--results-md", default=None, help="also replace the '## Learning' section of this Markdown file")
    p.add_argument("--json", action="store_true", help="print exactly one JSON object on stdout")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import torch

    from plmarl_sitl.learning.eval.evaluate import evaluate_methods, needed_policies
    from plmarl_sitl.learning.eval.report import write_outputs
    from plmarl_sitl.learning.nn.io import load_policy
    from plmarl_sitl.mission import load_mission

    torch.set_num_threads(1)
    if args.episodes < 2:
        raise UserError("--episodes must be >= 2 (a confidence interval needs two episodes)")
    if not 0.0 <= args.failure_prob <= 1.0:
        raise UserError("--failure-prob must be in [0, 1]")
    mission = load_mission(args.mission)
    loaded = {m: load_policy(Path(args.policies) / m, mission) for m in sorted(needed_policies(args.methods))}
    decisions = math.ceil(mission.timing.episode_s / mission.timing.decision_every_s)
    from plmarl_sitl.learning.eval.methods import GLOBAL_KNOWLEDGE

    runs = sum(1 if m in GLOBAL_KNOWLEDGE else len(args.tup) for m in args.methods)  # global knowledge: once
    total = decisions * args.episodes * runs
    with progress(disable=args.json) as bar:
        task = bar.add_task(f"eval {','.join(args.methods)} on {mission.name} (seed {args.seed})", total=total)
        res = evaluate_methods(
            mission, loaded, args.methods, args.tup, args.episodes, args.seed,
            from_s=args.from_s, failure_prob=args.failure_prob, on_decision=lambda b: bar.advance(task, b),
        )
    import shlex
    import sys

    res["extra"]["command"] = "plmarl " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    if args.out or args.results_md:
        write_outputs(res, mission, loaded, Path(args.out or "runs/eval"), args.results_md, args)
    if args.json:
        print(json.dumps({"results": res["results"], "p_values": res["p_values"], "policies": args.policies}))
    else:
        from plmarl_sitl.learning.eval.report import print_tables

        print_tables(res)
    return 0
