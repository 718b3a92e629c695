"""What the whole-mission tests on real autopilots (ArduCopter, PX4) share: the CLI under
nice, an environment that finds this checkout, free SITL instances, the recorded metrics."""

from __future__ import annotations

import json
import os
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
NICE = ["nice", "-n", "10"]


def cli(*args: str) -> list[str]:
    return [*NICE, sys.executable, "-m", "plmarl_sitl.cli", *args]


def env() -> dict[str, str]:
    return dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])))


def free_base(n: int, instances: range, instance_free: Callable[[int], bool], what: str) -> int:
    """The first of n consecutive free instances in `instances` (skips the test if none)."""
    for base in instances:
        if base + n <= instances.stop and all(instance_free(base + i) for i in range(n)):
            return base
    pytest.skip(f"no {n} free {what} in {instances.start}..{instances.stop - 1}")


def rows(out: Path) -> list[dict]:
    return [json.loads(x) for x in (out / "metrics.jsonl").read_text().splitlines() if x.strip()]
