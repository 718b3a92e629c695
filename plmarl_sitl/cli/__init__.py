"""`plmarl` command line: one subcommand per module in this package.

Each module listed in SUBCOMMANDS defines `register(subparsers)`, which adds its parser
and sets `func` (args -> exit code). User errors (bad YAML, bad flags, missing files) are
`UserError`/`ConfigError` and print one line on stderr with exit code 2, no traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from plmarl_sitl.config import ConfigError
from plmarl_sitl.errors import UserError

SUBCOMMANDS = ["sim", "bench", "autopilot", "train", "eval"]

EPILOG = """\
examples:
  plmarl sim missions/paper_urban.yaml --method oracle --episodes 20 --seed 1
  plmarl bench dt --json

Every run takes --seed and prints it; the same seed gives the same numbers."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="plmarl",
        description="PL-MARL swarm coverage: digital twin, training and MAVLink SITL deployment.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in SUBCOMMANDS:
        importlib.import_module(f"plmarl_sitl.cli.{name}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except (ConfigError, UserError) as exc:
        print(f"plmarl {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"plmarl {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
