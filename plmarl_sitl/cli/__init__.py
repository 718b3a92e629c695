"""`plmarl` command line: one subcommand per module in this package.

Each module listed in SUBCOMMANDS defines `register(subparsers)`, which adds its parser
and sets `func` (args -> exit code). Failures a user can cause or meet print one line on
stderr and exit non-zero, no traceback (`errors.run_reporting`): user errors (bad YAML,
bad flags, missing files) 2, a vehicle that refuses or goes silent 3, Ctrl-C 130.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from plmarl_sitl.errors import run_reporting

SUBCOMMANDS = ["sim", "bench", "autopilot", "train", "eval", "suite", "world", "agent", "report", "swarm"]

EPILOG = """\
examples:
  plmarl sim missions/paper_urban.yaml --method service --episodes 20 --seed 1
  plmarl bench dt --json

Every run takes --seed and prints it; the same seed gives the same numbers."""


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="plmarl",
        description="PL-MARL swarm coverage: digital twin, training and MAVLink SITL deployment.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    # `only`: register just the subcommand being run. Each subcommand module imports what
    # it needs (scipy, the twin, ...); an agent on a companion computer must not pay
    # start-up time and memory for the others.
    for name in [only] if only in SUBCOMMANDS else SUBCOMMANDS:
        importlib.import_module(f"plmarl_sitl.cli.{name}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = build_parser(argv[0] if argv else None)
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    return run_reporting(f"plmarl {args.command}", lambda: args.func(args))


if __name__ == "__main__":
    sys.exit(main())
