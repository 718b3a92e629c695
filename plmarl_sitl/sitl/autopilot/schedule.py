"""When each telemetry message of each vehicle is due, in sim time.

One heap per host orders all due messages of all vehicles; SET_MESSAGE_INTERVAL bumps a
per-(vehicle, message) generation so stale heap entries are skipped instead of searched for.
"""

from __future__ import annotations

import heapq
import itertools
import math

# Streams start on a per-vehicle grid (see Scheduler.set_rate): 0.1 s, the period of the
# 10 Hz streams, split into 5 phases, one per 50 Hz physics substep.
STREAM_GRID_S = 0.1
STREAM_PHASES = 5


class Scheduler:
    """Heap of (due sim time, vehicle, message) over all vehicles of a host."""

    def __init__(self, phases: int = STREAM_PHASES) -> None:
        self.phases = phases  # 1: every vehicle's streams on the same grid points (lockstep SITL)
        # (due, tie, (vehicle, msgid), generation): the tie (a counter) makes every entry's
        # (due, tie) unique, so the heap pops in one order however it is laid out
        self._heap: list[tuple[float, int, tuple[int, int], int]] = []
        self._tie = itertools.count()
        self._gen: dict[tuple[int, int], int] = {}
        self._interval: dict[tuple[int, int], float] = {}

    def set_rate(self, vehicle: int, msgid: int, hz: float, now: float) -> None:
        """Stream `msgid` of `vehicle` at `hz` (0 stops it), starting at the vehicle's next
        grid point: each vehicle's streams share one phase on a STREAM_GRID_S grid, so
        its 1 Hz messages fall on its 10 Hz ones and leave in the same datagram (as PX4
        bundles), and the phase differs between vehicles, so N vehicles' telemetry (and
        their agents' work) does not all land in the same instant."""
        key = (vehicle, msgid)
        gen = self._gen.get(key, 0) + 1
        self._gen[key] = gen
        if hz <= 0:
            self._interval.pop(key, None)
            return
        self._interval[key] = 1.0 / hz
        # Lockstep (one phase): a slower stream starts on its own period's grid, so a 5 Hz or 1 Hz
        # stream also has a sample at every whole second, where an agent's second begins.
        grid = STREAM_GRID_S if self.phases > 1 else max(STREAM_GRID_S, 1.0 / hz)
        phase = (vehicle % self.phases) * grid / self.phases
        first = phase + math.ceil((now - phase) / grid - 1e-9) * grid
        heapq.heappush(self._heap, (first, next(self._tie), key, gen))

    def rate(self, vehicle: int, msgid: int) -> float:
        iv = self._interval.get((vehicle, msgid))
        return 1.0 / iv if iv else 0.0

    def next_due(self) -> float:
        """Sim time of the earliest scheduled message (a stale entry may make it early, never late)."""
        return self._heap[0][0] if self._heap else math.inf

    def pop_due(self, now: float) -> list[tuple[int, int]]:
        """(vehicle, msgid) pairs due at `now`, each rescheduled one interval later."""
        out = []
        heap, gens, intervals, tie = self._heap, self._gen, self._interval, self._tie
        while heap and heap[0][0] <= now + 1e-9:
            due, _, key, gen = heap[0]
            if gens.get(key) != gen:
                heapq.heappop(heap)
                continue
            iv = intervals[key]
            nxt = due + iv
            if nxt < now - iv:  # far behind (e.g. a huge advance): do not burst
                nxt = now + iv
            heapq.heapreplace(heap, (nxt, next(tie), key, gen))  # the pop and the push in one sift
            out.append(key)
        return out
