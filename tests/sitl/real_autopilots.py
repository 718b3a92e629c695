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

import psutil
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


def names(procs: list[psutil.Process]) -> list[str]:
    """The names of those of `procs` still running."""
    out = []
    for p in procs:
        try:
            out.append(p.name())
        except psutil.NoSuchProcess:
            pass
    return out


class Started:
    """The CLI processes a test starts by hand (a world, autopilots, agents), each in a session
    of its own with its output in DIR/NAME.log; `interrupt` ends them as Ctrl-C would."""

    def __init__(self, directory: Path) -> None:
        self.dir = directory
        self.procs: list[subprocess.Popen] = []

    def start(self, args: list[str], name: str) -> subprocess.Popen:
        f = open(self.dir / f"{name}.log", "w")  # noqa: SIM115 - closed when the test's processes end
        p = subprocess.Popen(cli(*args), cwd=self.dir, env=env(), stdout=f, stderr=subprocess.STDOUT, start_new_session=True)
        self.procs.append(p)
        return p

    def logs(self) -> str:
        return "\n".join(f"--- {p.name}\n{p.read_text()[-1500:]}" for p in sorted(self.dir.glob("*.log")))

    def interrupt(self) -> None:
        interrupt_all(self.procs)


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
