"""Small pieces shared by the CLI subcommands."""

from __future__ import annotations

import argparse
import sys

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn


def add_seed(p: argparse.ArgumentParser, default: int | None = 0) -> None:
    said = "the mission's seed" if default is None else default
    p.add_argument("--seed", type=int, default=default, help=f"random seed; same seed, same numbers (default: {said})")


def tup_arg(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"T_up must be a whole number of seconds, got {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError("T_up must be >= 1 s")
    return v


def progress(disable: bool = False) -> Progress:
    """A rich progress bar on stderr, so stdout stays clean for --json."""
    return Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=Console(file=sys.stderr),
        disable=disable,
        transient=False,
    )
