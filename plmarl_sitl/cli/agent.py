"""`plmarl agent`: the agent program (`plmarl_sitl.deploy.agent.program`) as a subcommand."""

from __future__ import annotations

import argparse

from plmarl_sitl.deploy.agent import program


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "agent",
        help=program.HELP,
        description=program.DESCRIPTION,
        epilog=program.EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    program.add_arguments(p)
    p.set_defaults(func=program.run)
