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
its own setpoint-loss failsafe holds it, as with any companion computer that dies.
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

    def overdue(self, owing: Sequence[int], wall_s: float) -> list[int]:
        """Members that have owed the same answer for straggler_s or more."""
        late = []
        for i in owing:
            ms = int(self.fleet.telemetry_ms[i])
            since = self._owed_since.get(i)
            if since is None or since[0] != ms:
                self._owed_since[i] = (ms, wall_s)
            elif wall_s - since[1] >= self.straggler_s:
                late.append(i)
        return late

    def wait_left(self, owing: Sequence[int], wall_s: float) -> float:
        """Wall seconds until the first of `owing` would be overdue (inf: none owes)."""
        left = math.inf
        for i in owing:
            since = self._owed_since.get(i)
            left = min(left, self.straggler_s - (wall_s - since[1]) if since is not None else self.straggler_s)
        return max(0.0, left)

    def fail(self, i: int, why: str) -> None:
        self.failed.setdefault(i, why)
        self._failed_mask[i] = True
        self._owed_since.pop(i, None)
