"""The lockstep world's barrier: which agents the clock waits for, and when one has failed.

In lockstep (`SitlWorld` with `WorldConfig.lockstep`) vehicle time moves one physics
substep at a time, and only once every *member* has answered the latest LOCAL_POSITION_NED
its vehicle sent with a setpoint stamped with that telemetry's time_boot_ms (the fleet
records both: `Fleet.telemetry_ms`, `Fleet.answered_ms`), as PX4's lockstep waits for the
actuator outputs of each sensor message. A member is a live vehicle whose agent has
joined (sent a stamped setpoint: `plmarl agent --lockstep` does from its first one) and
has not been declared failed. An agent still starting up (arming, taking off) is not a
member yet: start-up is a wall-clock command exchange and is not lockstepped.

A member that owes an answer for `straggler_s` of wall time (stopped, crashed, hung) is
declared failed: the world stops waiting for it, its vehicle gets no more setpoints and
its own setpoint-loss failsafe holds it, as with any companion computer that dies. The
bound counts only time in which the swarm made no progress: it restarts at every answer
from any member (`Fleet.answered_wall`) and when the world sends the tick the answers wait
for (`restart`). A straggler is the one left owing once the others are done; a machine so
loaded that 100 agents take more than the bound to get through a map instant between them
(issue 25: every agent was declared failed at once at t = 0, 30 or 60 at load 30-60) is not.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # the CLI reads DEFAULT_STRAGGLER_S without importing torch
    from plmarl_sitl.sitl.autopilot.fleet import Fleet

DEFAULT_STRAGGLER_S = 10.0  # wall s an agent may owe an answer before it is declared failed
# Start-up (arming, take-off) is a wall-clock exchange and is not lockstepped: it runs at
# --speedup. At real time it would add ~35 s of wall time to every lockstep run; 10x is
# what free-running swarms of 20 keep up with on a 2-core machine.
DEFAULT_STARTUP_SPEEDUP = 10.0


def speedup_or_default(speedup: float | None, lockstep: bool) -> float:
    """--speedup as given, else real time (free-running) or DEFAULT_STARTUP_SPEEDUP (lockstep)."""
    if speedup is not None:
        return speedup
    return DEFAULT_STARTUP_SPEEDUP if lockstep else 1.0


class Barrier:
    """Which members the clock waits for. Called every physics substep with 20+ vehicles,
    so the bookkeeping is numpy masks over the fleet's arrays, not per-vehicle Python."""

    def __init__(self, fleet: Fleet, straggler_s: float = DEFAULT_STRAGGLER_S) -> None:
        if not straggler_s > 0:
            raise ValueError("straggler_s must be > 0")
        self.fleet = fleet
        self.straggler_s = straggler_s
        self.failed: dict[int, str] = {}  # vehicle -> why its agent was declared failed
        self._failed_mask = np.zeros(len(fleet.answered_ms), dtype=bool)
        self._owed_since: dict[int, tuple[int, float]] = {}  # vehicle -> (telemetry ms owed, wall s first seen owing)
        self._restarted = -math.inf  # wall s the world last made answering possible (a tick out)

    def _member_mask(self, alive: Sequence[bool]) -> np.ndarray:
        return np.asarray(alive, dtype=bool) & (self.fleet.answered_ms > 0) & ~self._failed_mask

    def members(self, alive: Sequence[bool]) -> list[int]:
        return np.flatnonzero(self._member_mask(alive)).tolist()

    def all_joined(self, alive: Sequence[bool]) -> bool:
        """Every live vehicle's agent has joined (or failed): the clock no longer needs a wall pace."""
        waiting = np.asarray(alive, dtype=bool) & (self.fleet.answered_ms <= 0) & ~self._failed_mask
        return not waiting.any()

    def owing(self, alive: Sequence[bool]) -> list[int]:
        """Members whose latest telemetry is not answered yet."""
        f = self.fleet
        return np.flatnonzero(self._member_mask(alive) & (f.answered_ms < f.telemetry_ms)).tolist()

    def restart(self, wall_s: float) -> None:
        """The world has just made answering possible again (it sent the tick the first
        telemetry of a second waits for): what the members owed before counts from now."""
        self._restarted = wall_s

    def _progress(self) -> float:
        """Wall s of the swarm's last progress: an answer from any member, or a restart."""
        return max(self._restarted, self.fleet.answered_wall)

    def overdue(self, owing: Sequence[int], wall_s: float) -> list[int]:
        """Members that have owed the same answer for straggler_s or more, with no answer
        from any member and no restart in that time."""
        late = []
        progress = self._progress()
        for i in owing:
            ms = int(self.fleet.telemetry_ms[i])
            since = self._owed_since.get(i)
            if since is None or since[0] != ms:
                self._owed_since[i] = (ms, wall_s)
            elif wall_s - max(since[1], progress) >= self.straggler_s:
                late.append(i)
        return late

    def wait_left(self, owing: Sequence[int], wall_s: float) -> float:
        """Wall seconds until the first of `owing` would be overdue (inf: none owes)."""
        left = math.inf
        progress = self._progress()
        for i in owing:
            since = self._owed_since.get(i)
            t = wall_s if since is None else max(since[1], progress)
            left = min(left, self.straggler_s - (wall_s - t))
        return max(0.0, left)

    def fail(self, i: int, why: str) -> None:
        self.failed.setdefault(i, why)
        self._failed_mask[i] = True
        self._owed_since.pop(i, None)
