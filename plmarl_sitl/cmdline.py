"""Argument types and the progress bar shared by the `plmarl` commands and the benchmarks
(a module of its own so that `bench/` need not import the CLI package above it)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Collection
from typing import TypeVar

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

T = TypeVar("T")


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


def comma_list(convert: Callable[[str], T], what: str, *, positive: bool = False,
               choices: Collection[T] | None = None) -> Callable[[str], list[T]]:
    """An argparse `type` for 'A,B,C': each item converted, checked, and named in the error."""

    def parse(text: str) -> list[T]:
        out = []
        for part in (p.strip() for p in text.split(",") if p.strip()):
            try:
                v = convert(part)
            except ValueError:
                raise argparse.ArgumentTypeError(f"{part!r} is not a valid {what}") from None
            if positive and not v > 0:  # type: ignore[operator]
                raise argparse.ArgumentTypeError(f"{what} must be > 0, got {part!r}")
            if choices is not None and v not in choices:
                raise argparse.ArgumentTypeError(f"{what} {part!r} is not one of {', '.join(map(str, choices))}")
            out.append(v)
        if not out:
            raise argparse.ArgumentTypeError(f"give at least one {what}")
        return out

    return parse


def rt_priority_arg(low: int = 1) -> Callable[[str], int]:
    """An argparse `type` for a SCHED_FIFO priority, low..99 (`plmarl agent`: 1; a bench
    that takes 0 for "normal priority only": 0)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a priority ({low}-99)") from None
        if not low <= value <= 99:
            raise argparse.ArgumentTypeError(f"SCHED_FIFO priority {value} is outside {low}-99")
        return value

    return parse


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
