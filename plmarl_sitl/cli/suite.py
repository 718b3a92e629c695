"""`plmarl suite`: the held-out evaluation suite (named scenario families, evaluation seeds)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from plmarl_sitl.cmdline import comma_list, progress
from plmarl_sitl.config import PROJECT_POLICIES, PROJECT_SUITE
from plmarl_sitl.learning.eval.methods import methods_help, parse_methods

DEFAULT_METHODS = "pl-marl,gru,tag-mappo,dead-reckoning,service,greedy,clairvoyant"


def _methods(text: str) -> list[str]:
    try:
        return parse_methods(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "suite",
        help="run the held-out evaluation suite (scenario families the policies never saw)",
        description="Run deterministic policies and baselines on named scenario families (defined in the project's "
        "missions/suite/suite.yaml: each a list of mission YAMLs): random connected layouts, moved clusters, launch "
        "elsewhere, RPGM mobility, zero-shot N = 8/12/20, node failure at t = 100 s, failures that need a re-plan "
        "(2 of 6 UAVs, in transit, splitting the swarm, diffuse clusters; method service-fixed is the plan follower "
        "without re-plans), moving demand, more or fewer UAVs than clusters, fast crowds, a long thin area, diffuse "
        "clusters (`plmarl suite --list` says each), and the paper map as a reference. Each family's episodes are spread over its missions; every method sees the same episodes.\n\n"
        "Seeds: every twin here is seeded from the evaluation range (>= 1_000_000_000: batch k of mission v of "
        "run --seed S uses 1_000_000_000 + 10000 S + 100 v + k). Training refuses twin seeds in that range "
        "(plmarl_sitl/learning/train/seeds.py), so no suite episode is a training episode.\n\n"
        "Each row: coverage (mean C(t) for t > --from-s, mean and 95% CI over episodes), the mean per-episode "
        "fraction of the best reference on the same episodes and which reference that was (per episode the best of "
        "service, greedy and clairvoyant among the methods run; none is a proven bound: a reference a method beats "
        "is no ceiling), lambda_2, and PL-MARL against the row's method: the two-sided Mann-Whitney U p-value "
        "(unpaired), the two-sided Wilcoxon signed-rank p-value of the per-episode differences (paired: every "
        "method flies the same episodes, so this is the test of the design) and the episodes PL-MARL wins and "
        "loses; failure families add the transient against the same best reference "
        "(trough, time to plateau; definitions in plmarl_sitl/learning/eval/transient.py). "
        "greedy and clairvoyant ignore signalling, so they run once per family and serve every T_up. "
        "results.json keeps every episode's coverage (and, on failure families, its level from 30 s after the "
        "failure), so --compare A,B can test any other pair, then or later (--results).\n\n"
        "Methods: " + methods_help() + ". ('oracle' is still accepted for greedy, for one release.)",
        epilog="examples:\n  plmarl suite all --episodes 30 --tup 5,15,50 --out runs/suite\n"
        "  plmarl suite random,launch --episodes 10 --json\n"
        "  plmarl suite random,failure --methods service,pl-marl,greedy,clairvoyant --tup 15 --episodes 10\n"
        "  plmarl suite failure_2of6 --methods pl-marl,pl-marl-resolve,greedy --tup 50 --compare pl-marl,pl-marl-resolve\n"
        "  plmarl suite --results runs/suite --compare pl-marl,service   # any pair of a run already made\n"
        "  plmarl suite --list",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("families", nargs="?", default=None, help="'all' or a comma list of family names (see --list)")
    p.add_argument("--list", action="store_true", help="list the suite's families and exit")
    p.add_argument("--suite-file", default=str(PROJECT_SUITE), help="suite YAML (default: the project's missions/suite/suite.yaml)")
    p.add_argument("--methods", type=_methods, default=DEFAULT_METHODS.split(","),
                   help=f"comma list (default: {DEFAULT_METHODS})")
    p.add_argument("--tup", type=comma_list(int, "T_up", positive=True), default=[5, 15, 50],
                   help="T_up values for families that do not pin their own (default: 5,15,50)")
    p.add_argument("--episodes", type=int, default=30, help="episodes per family and T_up (default: 30)")
    p.add_argument("--seed", type=int, default=0, help="suite run seed 0..99999, picks the evaluation seeds (default: 0)")
    p.add_argument("--policies", default=str(PROJECT_POLICIES),
                   help="directory holding <method>/{predictor.pt,policy.pt,card.yaml} (default: the project's policies/)")
    p.add_argument("--from-s", type=int, default=50, help="steady-state window starts after this many seconds (default: 50)")
    p.add_argument("--out", default=None, help="write results.json, results.md and PNG plots here")
    p.add_argument("--json", action="store_true", help="print exactly one JSON object on stdout (no traces)")
    p.add_argument("--compare", default=None, metavar="A,B",
                   help="also compare method A with method B on the same episodes, per family and T_up (paired "
                   "Wilcoxon, Mann-Whitney, wins/losses; on failure families also from 30 s after the failure); "
                   "with --results, compare them in a run already made instead of running")
    p.add_argument("--results", type=Path, default=None, metavar="PATH",
                   help="with --compare: a run's results.json (or its --out directory); nothing is run")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import shlex
    import sys
    import time
    from datetime import UTC, datetime

    import torch

    from plmarl_sitl.errors import UserError
    from plmarl_sitl.learning.eval.suite import decisions, load_policies, load_suite, run_suite, select
    from plmarl_sitl.learning.eval.suite_compare import compare_methods, comparison_md, load_results, parse_pair
    from plmarl_sitl.learning.eval.suite_report import print_summary, write_outputs
    from plmarl_sitl.learning.pipeline import git_commit
    from plmarl_sitl.machine import machine_info

    pair = parse_pair(args.compare) if args.compare is not None else None
    if args.results is not None:
        if pair is None:
            raise UserError("--results reads a run for --compare A,B: name the two methods")
        if args.families is not None:
            raise UserError("--results compares a run already made: give no families to run")
        res = load_results(args.results)
        rows = compare_methods(res, *pair)
        print(json.dumps({"seed": res.get("seed"), "from_s": res.get("from_s"), "comparison": rows}) if args.json
              else comparison_md(res, rows))
        return 0
    if pair is not None and not set(pair) <= set(args.methods):
        raise UserError(f"--compare {args.compare}: both methods must be among --methods ({','.join(args.methods)})")
    torch.set_num_threads(1)
    spec, families = load_suite(args.suite_file)
    if args.list:
        width = max(len(f.name) for f in spec.families)
        for f in spec.families:
            print(f"{f.name:{width}s} {f.about}")
        return 0
    if args.families is None:
        raise UserError("name the families to run ('all' or a comma list; see plmarl suite --list)")
    chosen = [families[n] for n in select(spec, args.families)]
    loaded = load_policies(chosen, args.methods, args.policies)
    total = sum(decisions(f, args.episodes, args.tup, args.methods) for f in chosen)
    # The commit and date of the code that runs: read at the start, since a long suite can
    # outlast a commit made beside it.
    commit, started = git_commit(), datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC")
    t0 = time.time()
    with progress(disable=args.json) as bar:
        task = bar.add_task("suite", total=total)
        res = run_suite(
            chosen, loaded, args.methods, args.tup, args.episodes, args.seed, from_s=args.from_s,
            on_decision=lambda b: bar.advance(task, b),
            on_family=lambda name: bar.update(task, description=f"suite {name} (seed {args.seed})"),
        )
    res.update({
        "command": "plmarl " + " ".join(shlex.quote(a) for a in sys.argv[1:]),
        "suite_file": args.suite_file, "policies": args.policies, "commit": commit, "machine": machine_info(),
        "date": started, "wall_s": round(time.time() - t0, 1),
        "torch_threads": 1,
    })
    if pair is not None:
        res["comparison"] = compare_methods(res, *pair)
    if args.out:
        write_outputs(res, list(spec.scaling), Path(args.out))
    if args.json:
        print(json.dumps({k: v for k, v in res.items() if k != "traces"}))
    else:
        print_summary(res)
        if pair is not None:
            print()
            print(comparison_md(res, res["comparison"]))
    return 0
