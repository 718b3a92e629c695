"""What an agent measures and records: loop timing, memory, start-up, the per-second
trace (`--trace`) and the summary written on exit (`--stats-json`)."""

from __future__ import annotations

import json
import os
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO


@dataclass
class LoopStats:
    """Decision-loop timing: telemetry message handled -> setpoint sent (wall ms)."""

    all_ms: deque[float] = field(default_factory=lambda: deque(maxlen=200_000))
    decision_ms: deque[float] = field(default_factory=lambda: deque(maxlen=200_000))
    # CPU time of the same ticks: what the code costs, without the time the OS gave the
    # core to other processes mid-tick (which the wall figure includes on a loaded machine).
    decision_cpu_ms: deque[float] = field(default_factory=lambda: deque(maxlen=200_000))
    # From the telemetry datagram's arrival in the kernel (UDP links): also the time the
    # message waited for this process to get a CPU and read it.
    decision_arrival_ms: deque[float] = field(default_factory=lambda: deque(maxlen=200_000))
    startup_s: float | None = None
    decisions: int = 0
    seconds: int = 0
    # Telemetry samples answered after the mission start: against seconds x the telemetry
    # rate, the share a free-running agent keeps up with (it skips to the newest sample
    # when it falls behind; a lockstep one answers every sample).
    mission_samples: int = 0
    telemetry_hz: float = 0.0  # the in-flight rate the agent asked for (lockstep asks for less)

    def tick(self, t_in: float, c_in: float, decided: bool, rx_ns: int | None, in_mission: bool = False) -> None:
        """One telemetry message handled, from perf_counter t_in and thread_time c_in (its
        datagram arrived at time_ns rx_ns, when the link stamps arrivals)."""
        dt_ms = (time.perf_counter() - t_in) * 1e3
        self.all_ms.append(dt_ms)
        self.mission_samples += in_mission
        if decided:
            self.decision_ms.append(dt_ms)
            self.decision_cpu_ms.append((time.thread_time() - c_in) * 1e3)
            if rx_ns is not None:
                self.decision_arrival_ms.append((time.time_ns() - rx_ns) / 1e6)

    def summary(self) -> dict[str, float | int | None]:
        def pct(xs: deque[float], q: float) -> float | None:
            if not xs:
                return None
            s = sorted(xs)
            return s[min(len(s) - 1, int(q * len(s)))]

        return {
            "loop_p50_ms": pct(self.decision_ms, 0.5),
            "loop_p99_ms": pct(self.decision_ms, 0.99),
            "loop_cpu_p50_ms": pct(self.decision_cpu_ms, 0.5),
            "loop_cpu_p99_ms": pct(self.decision_cpu_ms, 0.99),
            "arrival_p50_ms": pct(self.decision_arrival_ms, 0.5),
            "arrival_p99_ms": pct(self.decision_arrival_ms, 0.99),
            "all_p50_ms": pct(self.all_ms, 0.5),
            "all_p99_ms": pct(self.all_ms, 0.99),
            "startup_s": self.startup_s,
            "decisions": self.decisions,
            "seconds": self.seconds,
            "mission_samples": self.mission_samples,
            "telemetry_hz": self.telemetry_hz,
        }


def rss_mb() -> float:
    try:
        import psutil

        return float(psutil.Process().memory_info().rss / 2**20)
    except Exception:  # noqa: BLE001 - best effort
        return float("nan")


def process_start_time() -> float:
    """Unix time this process started (so start-up includes the interpreter and imports).

    From /proc/self/stat's start time (clock ticks since boot) and CLOCK_BOOTTIME, both
    on the boot clock: good to a tick (10 ms). psutil's create_time() adds the tick count
    to /proc/stat's btime, which is truncated to a whole second, so it can place the start
    up to a second too early."""
    try:
        with open("/proc/self/stat") as f:
            ticks = int(f.read().rsplit(")", 1)[1].split()[19])
        age = time.clock_gettime(time.CLOCK_BOOTTIME) - ticks / os.sysconf("SC_CLK_TCK")
        return time.time() - age
    except (OSError, ValueError, IndexError, AttributeError):  # not Linux: count from now
        return time.time()


class Trace:
    """One JSON line per mission second (`--trace`), line-buffered so a killed agent
    leaves whole lines; inactive (and free) without a path."""

    def __init__(self, path: Path | None) -> None:
        self.path = path
        self._file: IO[str] | None = None

    @property
    def active(self) -> bool:
        return self._file is not None

    def open(self) -> None:
        if self.path is not None:
            self._file = open(self.path, "w", buffering=1)  # noqa: SIM115 - closed by close()

    def write(self, record: dict) -> None:
        assert self._file is not None
        self._file.write(json.dumps(record) + "\n")

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None


def write_stats(path: Path, loop: LoopStats, extra: dict[str, object]) -> None:
    """The summary on exit (`--stats-json`): loop timing, RSS, the last 5000 samples of
    each decision timing, then `extra` (the agent's counters), then the pid."""
    out = {
        **loop.summary(),
        "rss_mb": rss_mb(),
        "decision_ms_samples": [round(x, 4) for x in list(loop.decision_ms)[-5000:]],
        "decision_cpu_ms_samples": [round(x, 4) for x in list(loop.decision_cpu_ms)[-5000:]],
        "decision_arrival_ms_samples": [round(x, 4) for x in list(loop.decision_arrival_ms)[-5000:]],
        **extra,
        "pid": os.getpid(),
    }
    Path(path).write_text(json.dumps(out))
