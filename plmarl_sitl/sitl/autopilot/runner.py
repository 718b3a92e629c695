"""Standalone clock owner: advance a host by wall time × speedup.

Used by `plmarl autopilot` and the benchmark. Sim time follows the wall clock exactly as
long as the process keeps up; when it cannot (overload), each tick advances at most
`max_catchup_ticks` ticks' worth, so sim time falls behind instead of the physics taking
huge steps, and `RunStats.realtime_factor` shows it.
"""

from __future__ import annotations

import asyncio
import logging
import time
from dataclasses import dataclass

from plmarl_sitl.sitl.autopilot.host import AutopilotHost

log = logging.getLogger("plmarl.autopilot")

CHUNK_SUBSTEPS = 4


@dataclass
class RunStats:
    wall_s: float = 0.0
    sim_s: float = 0.0
    cpu_s: float = 0.0
    ticks: int = 0
    late_ticks: int = 0  # ticks that started more than one tick period late

    @property
    def realtime_factor(self) -> float:
        return self.sim_s / self.wall_s if self.wall_s > 0 else 0.0

    @property
    def cpu_load(self) -> float:
        """Share of one core this process used (1.0 = saturated)."""
        return self.cpu_s / self.wall_s if self.wall_s > 0 else 0.0


async def run_realtime(
    host: AutopilotHost,
    speedup: float = 1.0,
    *,
    tick_hz: float = 50.0,
    duration_s: float | None = None,
    stop: asyncio.Event | None = None,
    log_every_s: float = 10.0,
    max_catchup_ticks: int = 5,
) -> RunStats:
    """Drive `host` until `stop` is set, `duration_s` of wall time pass, or cancellation."""
    if speedup <= 0:
        raise ValueError("speedup must be > 0")
    period = 1.0 / tick_hz
    stats = RunStats()
    t0 = last = time.perf_counter()
    cpu0 = time.process_time()
    sim0 = host.now
    next_tick = t0 + period
    next_log = t0 + log_every_s
    try:
        while stop is None or not stop.is_set():
            delay = next_tick - time.perf_counter()
            if delay > 0:
                await asyncio.sleep(delay)
            else:
                stats.late_ticks += delay < -period
                await asyncio.sleep(0)  # let datagrams in even when overloaded
            now = time.perf_counter()
            todo = min(now - last, max_catchup_ticks * period) * speedup
            last = now
            # At high speedups one tick is many substeps: hand the loop back between chunks
            # so incoming datagrams are read steadily instead of piling up in the socket.
            chunk = CHUNK_SUBSTEPS * host.physics_dt
            while todo > chunk:
                host.advance(chunk)
                todo -= chunk
                await asyncio.sleep(0)
            host.advance(todo)
            stats.ticks += 1
            next_tick = max(next_tick + period, now - period)
            if duration_s is not None and now - t0 >= duration_s:
                break
            if now >= next_log:
                next_log = now + log_every_s
                host.log_counters()
    finally:
        stats.wall_s = time.perf_counter() - t0
        stats.sim_s = host.now - sim0
        stats.cpu_s = time.process_time() - cpu0
    return stats
