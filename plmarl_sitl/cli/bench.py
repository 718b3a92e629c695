"""`plmarl bench TARGET`: the speed figures each part of the toolkit is judged by.

Each target lives in plmarl_sitl/bench/<target>.py with `add_arguments(parser)` and
`run(args) -> dict`. Results print as a table, or as one JSON object with --json.
"""

from __future__ import annotations

import argparse
import importlib
import json

TARGETS = {
    "autopilot": "vehicles one autopilot-emulator process sustains at 1x, and the speedup 20 vehicles sustain",
    "dt": "speed of the vectorised digital twin (agent-steps/s) and of one greedy-reference episode",
    "agent": "deployed agent in SITL: decision-loop latency, RSS and start-up at N = 20, speedup 10",
    "infer": "per-agent decision latency of the exported policies (PL-MARL vs GRU), N = 4..20",
    "swarm": "wall time of the 200 s mission as a SITL swarm (N = 4, 20) at the fastest speedup with coverage gap <= 0.03",
}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "bench",
        help="measure speed (twin, inference, autopilot, agent, swarm)",
        description="Measure the speed figures of the toolkit. Results go to stdout; "
        "docs/RESULTS.md records them with the machine and the command.",
    )
    tsub = p.add_subparsers(dest="target", metavar="TARGET", required=True)
    for name, help_text in TARGETS.items():
        mod = importlib.import_module(f"plmarl_sitl.bench.{name}")
        tp = tsub.add_parser(name, help=help_text, description=help_text)
        tp.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
        mod.add_arguments(tp)
        tp.set_defaults(func=lambda args, mod=mod: _run(mod, args))


def _run(mod, args: argparse.Namespace) -> int:
    result = mod.run(args)
    if args.json:
        print(json.dumps(result))
    else:
        mod.print_table(result)
    return 0
