"""Argument types, options declared once, and the progress bar shared by the `plmarl`
commands and the benchmarks (a module of its own so that `bench/` and `sitl/` need not
import the CLI package above them)."""

from __future__ import annotations

import argparse
import dataclasses
import math
import re
import sys
from collections.abc import Callable, Collection, Iterable
from typing import TYPE_CHECKING, Any, TypeVar

from plmarl_sitl.config import MAX_SEED

if TYPE_CHECKING:  # rich is imported where a table or bar is drawn: the agent (which takes this
    # module's argument types) never draws one, and every forked agent's RSS counts its ~2 MB
    from rich.console import Console
    from rich.progress import Progress

T = TypeVar("T")


def seed_arg(text: str) -> int:
    """An argparse `type` for a seed: a whole number in 0..MAX_SEED (every generator takes it)."""
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a seed (a whole number)") from None
    if not 0 <= v <= MAX_SEED:
        raise argparse.ArgumentTypeError(f"seed {v} is outside 0..{MAX_SEED}")
    return v


def add_seed(p: argparse.ArgumentParser, default: int | None = 0) -> None:
    said = "the mission's seed" if default is None else default
    p.add_argument("--seed", type=seed_arg, default=default,
                   help=f"random seed 0..{MAX_SEED}; same seed, same numbers (default: {said})")


# Sim seconds per wall second. Beyond ~1000x a free-running world's 50 Hz ticks are 20 s
# of physics each and the agents' wall-clock timeouts mean nothing; lockstep runs as fast
# as it computes whatever is given.
MAX_SPEEDUP = 1000.0


def speedup_arg(text: str) -> float:
    """An argparse `type` for --speedup: a finite number in (0, MAX_SPEEDUP]."""
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not (math.isfinite(v) and 0 < v <= MAX_SPEEDUP):
        raise argparse.ArgumentTypeError(f"speedup must be a finite number in (0, {MAX_SPEEDUP:g}], got {text!r}")
    return v


# A swarm name is one MQTT topic level (plmarl/<swarm>/...): no wildcard (+ #), no level
# separator, nothing a broker or a log line would mangle.
SWARM_NAME = re.compile(r"[A-Za-z0-9_.-]{1,64}")


def swarm_name_arg(text: str) -> str:
    """An argparse `type` for a swarm name: 1-64 of A-Z a-z 0-9 _ . - (one MQTT topic level)."""
    if not SWARM_NAME.fullmatch(text):
        raise argparse.ArgumentTypeError(
            f"swarm name {text!r}: use 1-64 letters, digits, '_', '.' or '-' (it is one MQTT topic level; + # / are not allowed)")
    return text


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


# --- options declared once ------------------------------------------------------------------
# An option is a field of a frozen dataclass that carries its default, its flag(s) and its
# help (`flag`); a command adds those fields to its parser (`add_flags`) and builds the
# dataclass from what was parsed (`from_flags`), and a program builds the same dataclass
# directly. So an option's name, default and meaning are written once.

FLAG = "plmarl.flag"  # the dataclass field metadata key


@dataclasses.dataclass(frozen=True)
class Flag:
    names: tuple[str, ...]  # "--name" first, then aliases; () for a positional argument
    help: str
    group: str | None  # flags of one mutually exclusive group share a name
    also: tuple[str, ...]  # other fields its action sets (one flag, two fields)
    argparse: dict[str, Any]  # type, metavar, choices, action, required


def flag(*names: str, help: str, default: Any = dataclasses.MISSING, group: str | None = None,  # noqa: A002
         also: tuple[str, ...] = (), **argparse_kw: Any) -> Any:
    """A dataclass field that is also a command-line argument: `names` (none: positional,
    named after the field), `help`, `default` (none: required), argparse's keywords."""
    return dataclasses.field(default=default, metadata={FLAG: Flag(names, help, group, also, argparse_kw)})


def flagged_fields(cls: type) -> list[dataclasses.Field]:
    return [f for f in dataclasses.fields(cls) if FLAG in f.metadata]


def add_flags(parser: Any, cls: type, *, skip: Iterable[str] = ()) -> None:
    """Add `cls`'s flagged fields (but `skip`) to `parser` (an ArgumentParser or one of its
    argument groups), each with its field's default."""
    skipped = set(skip)
    groups: dict[str, Any] = {}
    for f in flagged_fields(cls):
        if f.name in skipped:
            continue
        spec: Flag = f.metadata[FLAG]
        target: Any = parser
        if spec.group:
            if spec.group not in groups:
                groups[spec.group] = parser.add_mutually_exclusive_group()
            target = groups[spec.group]
        kw = dict(spec.argparse)
        if f.default is not dataclasses.MISSING:
            kw["default"] = f.default
        if spec.names:
            target.add_argument(*spec.names, dest=f.name, help=spec.help, **kw)
        else:
            target.add_argument(f.name, help=spec.help, **kw)


def from_flags(cls: type[T], args: argparse.Namespace, **given: Any) -> T:
    """`cls` from its parsed flags (those `args` has: a command may skip some), `given`
    taking precedence (what the command loaded or decided itself)."""
    names = [n for f in flagged_fields(cls) for n in (f.name, *f.metadata[FLAG].also)]
    found = {n: getattr(args, n) for n in names if hasattr(args, n)}
    return cls(**{**found, **given})


def progress(disable: bool = False) -> Progress:
    """A rich progress bar on stderr, so stdout stays clean for --json."""
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

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


def table_console() -> Console:
    """A console for result tables on stdout: the terminal's width on a terminal; piped to a
    file or another program, wide enough that no column is cut (rich assumes 80 columns
    there, and printed "covera…" and "tag-ma…")."""
    from rich.console import Console

    return Console() if sys.stdout.isatty() else Console(width=1000)
