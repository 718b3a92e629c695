"""`plmarl sim`: run episodes of a non-learned controller in the digital twin."""

from __future__ import annotations

import argparse
import json
import math

from plmarl_sitl.cmdline import add_seed, progress, table_console, tup_arg
from plmarl_sitl.learning.eval.methods import METHOD_HELP, canonical_method
from plmarl_sitl.mission import load_mission

METHODS = ("service", "service-local", "greedy", "clairvoyant", "heuristic")  # the controllers that need no trained policy


def _method(text: str) -> str:
    name = canonical_method(text)
    if name not in METHODS:
        raise argparse.ArgumentTypeError(f"invalid choice {text!r} (choose from {', '.join(METHODS)})")
    return name


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "sim",
        help="run episodes of a controller that needs no trained policy (service, service-local, greedy, clairvoyant, heuristic) in the digital twin",
        description="Run episodes of a mission in the vectorised digital twin with a non-learned "
        "controller and report mean coverage C (95% CI over episodes), lambda_2 and the closest "
        "approach of two UAVs. " + "; ".join(f"{m}: {METHOD_HELP[m]}" for m in METHODS) + ". "
        "None of them is a proven bound. ('oracle' is still accepted for greedy, for one release.)",
        epilog="examples:\n  plmarl sim missions/paper_urban.yaml --method service --episodes 20 --seed 1 --json\n"
        "  plmarl sim missions/paper_urban.yaml --method clairvoyant --episodes 4 --seed 1",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("mission", help="mission YAML, e.g. missions/paper_urban.yaml")
    p.add_argument("--method", type=_method, default="greedy", metavar="|".join(METHODS),
                   help="controller (default: greedy)")
    p.add_argument("--episodes", type=int, default=20, help="number of episodes (default: 20)")
    add_seed(p)
    p.add_argument("--tup", type=tup_arg, help="signalling interval T_up in seconds (default: the mission's)")
    p.add_argument("--json", action="store_true", help="print exactly one JSON object on stdout")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    # The twin (torch) and the statistics (scipy) are imported here, not at the top: `plmarl
    # --help` registers every subcommand and would pay ~4 s for them.
    from plmarl_sitl.learning.eval.evaluate import controller_factory
    from plmarl_sitl.learning.eval.stats import mean_ci95
    from plmarl_sitl.twin.rollout import run_episodes

    mission = load_mission(args.mission)
    if args.tup is not None:
        mission = mission.with_tup(args.tup)
    if args.episodes < 1:
        from plmarl_sitl.errors import UserError

        raise UserError("--episodes must be >= 1")
    decisions = math.ceil(mission.timing.episode_s / mission.timing.decision_every_s)
    with progress(disable=args.json) as bar:
        task = bar.add_task(f"{args.method} on {mission.name} (seed {args.seed})", total=args.episodes * decisions)
        res = run_episodes(
            mission, controller_factory(args.method, {}), args.episodes, args.seed, on_decision=lambda b: bar.advance(task, b)
        )
    mean, (lo, hi) = mean_ci95(res.coverage)
    out = {
        "coverage_mean": mean,
        "coverage_ci95": [lo, hi],
        "lambda2_mean": float(res.lambda2.mean()),
        "min_separation_m": float(res.min_separation.min()),
        "method": args.method,
        "episodes": args.episodes,
        "seed": args.seed,
    }
    if args.json:
        print(json.dumps(out))
        return 0
    from rich.table import Table

    t = Table(title=f"{args.method} on {mission.name}: {args.episodes} episodes, T_up {mission.signalling.tup_s} s, seed {args.seed}")
    t.add_column("metric")
    t.add_column("value", justify="right")
    t.add_row("coverage C (mean)", f"{mean:.3f}")
    t.add_row("coverage 95% CI", f"[{lo:.3f}, {hi:.3f}]")
    t.add_row("lambda_2 (mean)", f"{out['lambda2_mean']:.2f}")
    t.add_row("closest approach", f"{out['min_separation_m']:.1f} m (d_safe {mission.radii.safe_m:g} m)")
    table_console().print(t)
    return 0
