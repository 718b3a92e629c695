"""The agent's mission clock: which mission second is due, when a signalling instant closes.

Pure bookkeeping (no I/O, no event loop, no tensors), keyed to the VEHICLE clock
(LOCAL_POSITION_NED.time_boot_ms), so a `--speedup` run behaves like a real-time one:
mission second k = boot_s - t0. Every T_up seconds is a signalling instant: the agent
publishes its state there, waits a little for its neighbours' updates before processing
that second (`second_due`), and books the misses of the instant a grace period later
(`instants_to_book`), so a late update is not a miss.

Vehicle time runs `rate` times faster than wall time (the SITL speedup; 1 on a real
vehicle): the waits are bounded in wall time, so they are scaled by the observed rate.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable

from plmarl_sitl.deploy.mqtt.schema import INSTANT_WAIT_MIN_S

log = logging.getLogger("plmarl.agent")

EPS = 1e-9  # s: boot times are whole milliseconds, mission seconds whole numbers


def next_multiple(k: int, step: int) -> int:
    """The first multiple of `step` at or after k."""
    return -(-k // step) * step


class MissionClock:
    def __init__(self, tup: int, tau: int, settle_min_s: float, settle_wall_s: float, lockstep: bool = False) -> None:
        self.tup = tup  # signalling interval T_up, s
        self.tau = tau  # decision interval, s
        self.settle_min_s = settle_min_s  # vehicle s: an instant is never processed earlier
        self.settle_wall_s = settle_wall_s  # wall s: ... and at most this late (x the rate)
        # Lockstep SITL: the agent answers a second's first telemetry only once the world's
        # tick says everything of that second is in, so every second is processed there and
        # then, and an instant's misses are booked at the instant (no wall-clock bound).
        self.lockstep = lockstep
        self.boot_s = 0.0  # the vehicle's boot clock at the latest telemetry
        self.t0: float | None = None  # mission start on the boot clock; None: not started
        self.first_k = 0  # the first mission second this agent processes
        self.next_k = 0  # the next mission second to process
        self.next_pub_k: int | None = None  # the next instant to publish this agent's state at
        self.next_close: int | None = None  # the next signalling instant whose misses are unbooked
        self.closed_t = -math.inf  # the last signalling instant the SITL link emulator closed
        self.rate: float | None = None  # vehicle seconds per wall second
        self._rate_ref: tuple[float, float] | None = None  # (wall s, boot s) the rate is measured from

    # ------------------------------------------------------------------ inputs
    def observe(self, boot_s: float, wall_s: float) -> None:
        """A telemetry sample taken at vehicle time `boot_s`, handled at wall time `wall_s`
        (perf_counter): the rate is re-measured about every wall second, smoothed."""
        self.boot_s = boot_s
        if self._rate_ref is None:
            self._rate_ref = (wall_s, boot_s)
            return
        w0, b0 = self._rate_ref
        if wall_s - w0 >= 1.0:
            r = (boot_s - b0) / (wall_s - w0)
            if r > 0:
                self.rate = r if self.rate is None else 0.5 * self.rate + 0.5 * r
            self._rate_ref = (wall_s, boot_s)

    def set_t0(self, t0: float, origin: str = "") -> int:
        """Start the mission at boot time t0 (`origin`: what that instant is, for the log);
        returns the first second processed (the current one when the mission began before
        this agent did)."""
        self.t0 = t0
        k = max(0, math.ceil(self.boot_s - t0 - EPS))
        self.next_k = self.first_k = k
        self.next_close = next_multiple(k, self.tup)
        self.next_pub_k = next_multiple(k, self.tup)
        said = f", {origin}" if origin else ""
        log.info("mission clock: t0 = boot %.3f s (first second %d%s)", t0, k, said)
        return k

    def set_tup(self, tup: int) -> None:
        """A new signalling interval: the next instant is the next multiple of it.

        Lockstep: the world's instant at the second the change arrives in (`next_k`: its
        tick, which follows the change, is not in yet) follows the interval before the
        change, and the new one counts from the next second on. An instant still owed
        there under the old interval stays owed; nothing depends on whether that second's
        first telemetry came before the change, which is wall-clock order."""
        self.tup = tup
        if self.t0 is None:
            return
        if self.lockstep:
            k = self.next_k
            after = next_multiple(k + 1, tup)
            if self.next_pub_k != k:
                self.next_pub_k = after
            if self.next_close != k:
                self.next_close = after
            return
        k = math.ceil(self.boot_s - self.t0)
        self.next_pub_k = next_multiple(k, tup)
        self.next_close = self.next_pub_k

    def on_closed(self, t_s: float) -> None:
        """The SITL link emulator closed instant t_s (a late, older announcement moves nothing back)."""
        self.closed_t = max(self.closed_t, t_s)

    # ------------------------------------------------------------------ queries
    def in_mission(self) -> bool:
        return self.t0 is not None and self.boot_s >= self.t0

    def mission_s(self) -> float:
        assert self.t0 is not None
        return self.boot_s - self.t0

    def mission_now(self) -> float | None:
        """Mission time at the latest telemetry; None before t0 or any telemetry."""
        if self.t0 is None or self._rate_ref is None:
            return None
        return self.boot_s - self.t0

    def is_decision(self, k: int) -> bool:
        return k % self.tau == 0

    def settle_max_s(self) -> float:
        """Vehicle seconds an instant (or the first decision) waits at most."""
        return max(INSTANT_WAIT_MIN_S, self.settle_wall_s * (self.rate or 1.0))

    def grace_s(self) -> float:
        """How long after an instant an update still counts as delivered: 0.5 s of wall
        time (x the observed speedup), at least the decision wait, at most T_up / 2.
        Lockstep: none (no update of an instant arrives after the instant's tick)."""
        if self.lockstep:
            return 0.0
        return min(max(self.settle_max_s(), 0.5 * (self.rate or 1.0)), self.tup / 2)

    def states_due(self, tm: float) -> list[int]:
        """The signalling instants reached by mission time tm whose state is not yet
        published (usually none or one), marked published."""
        due = []
        while self.next_pub_k is not None and tm >= self.next_pub_k - EPS:
            due.append(self.next_pub_k)
            self.next_pub_k = next_multiple(self.next_pub_k + 1, self.tup)  # an old interval's instant may precede
        return due

    def second_due(self, k: int, tm: float, awaiting_sensing: bool, delivered: Callable[[int], bool],
                   awaiting_demand: bool = False) -> bool:
        """Second k can be processed at mission time tm: at once, except
        - at a signalling instant, which waits until every neighbour expected to deliver has
          (`delivered(k)`) or the SITL link emulator says the instant is closed,
        - at the first decision, which waits for a first sensing message
          (`awaiting_sensing`: is there a sensing publisher at all?); later decisions take
          the newest sensing there is, as a wait for second k's would delay every action
          by the bus's round trip, and
        - at a decision whose demand map is due and not here yet (`awaiting_demand`: the
          twin's decision at k sees the map of k),
        all bounded by `settle_max_s` of vehicle time, so late messages still count."""
        if tm < k - EPS:
            return False
        if self.lockstep:
            return True  # the tick for second k is in (or the broker is down: nothing more will come)
        instant = k % self.tup == 0
        first_sensing = self.is_decision(k) and awaiting_sensing
        demand = self.is_decision(k) and awaiting_demand
        if not instant and not first_sensing and not demand:
            return True
        if instant and tm < k + self.settle_min_s:
            return False
        if tm >= k + self.settle_max_s():
            return True
        if first_sensing or demand:
            return False
        if self.closed_t >= k:
            return True
        return delivered(k)

    def instants_to_book(self, k: int, sub_s: float = 0.0) -> list[int]:
        """The signalling instants whose grace period has passed by second k (processed
        `sub_s` late), oldest first, marked booked: their misses are counted now (the
        instant itself when the grace is under a second)."""
        due = []
        while self.next_close is not None and self.next_close + self.grace_s() <= k + sub_s:
            due.append(self.next_close)
            self.next_close = next_multiple(self.next_close + 1, self.tup)
        return due
