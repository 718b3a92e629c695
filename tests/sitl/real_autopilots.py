"""What the whole-mission tests on real autopilots (ArduCopter, PX4) share: the CLI under
nice, an environment that finds this checkout, free SITL instances, the recorded metrics."""

from __future__ import annotations

import json
import os
import signal
import subprocess
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


def interrupt_all(procs: list[subprocess.Popen]) -> None:
    """Ctrl-C every process still running, then SIGKILL the process group of any that has
    not exited 15 s later (each was started in a session of its own)."""
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
    for p in procs:
        try:
            p.wait(timeout=15)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
