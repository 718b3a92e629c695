"""The SITL world's clock: three ways to move vehicle time, one interface.

A pacer moves the vehicles' time and hands the world each whole second as it is reached
(`PacedWorld.whole_second`), with the relay pumped between (`Relay.pump`: overdue instants,
delayed deliveries). Which one a world runs follows from its vehicles and its options:

* `FreePacer`: emulated vehicles, free-running at wall time x speedup, in chunks that land
  exactly on every whole second; a stall is caught up only so far (`pace.Pace` says once
  when the mission falls behind its --speedup);
* `FollowPacer`: external vehicles keep clocks of their own; a second is processed once
  every live vehicle has reported it;
* `LockstepPacer`: emulated vehicles, one physics substep at a time, each once every
  member agent has answered its telemetry and the tick of the last second is out
  (`sitl.lockstep.Barrier`); start-up is paced at wall x speedup.

Before the mission the seconds are boot seconds; once the world announces t0
(`start_at`), mission seconds from t0.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from collections.abc import Callable
from typing import Protocol

import torch

from plmarl_sitl.deploy.mqtt.schema import Topics
from plmarl_sitl.deploy.mqtt.wire import Wire
from plmarl_sitl.sitl.autopilot.host import AutopilotHost
from plmarl_sitl.sitl.external import ExternalVehicles
from plmarl_sitl.sitl.lockstep import Barrier
from plmarl_sitl.sitl.network.relay import Relay
from plmarl_sitl.sitl.outbox import Outbox
from plmarl_sitl.sitl.pace import CATCHUP_TICKS, Pace
from plmarl_sitl.sitl.start import MissionTime
from plmarl_sitl.sitl.vehicles import WorldVehicles

log = logging.getLogger("plmarl.world")

CHUNK_S = 0.08  # sim seconds per advance between yields (4 substeps at 50 Hz)
FOLLOW_POLL_S = 0.1
QUIET_SUBSTEPS_MAX = 50  # lockstep: at most a second of substeps in one call (telemetry ends them sooner)  # wall: external vehicles silent this long: check the instants and the queue anyway


class PacedWorld(Protocol):
    """What a pacer drives: the world."""

    vehicles: WorldVehicles
    relay: Relay
    outbox: Outbox
    time: MissionTime
    wire: Wire
    topics: Topics
    stopping: asyncio.Event
    takeoff_alt: float
    agents_working: Callable[[list[int]], list[int]] | None

    @property
    def now(self) -> float: ...
    def whole_second(self, second: float) -> None: ...
    def alive(self) -> torch.Tensor: ...
    def not_ready(self) -> list[str]: ...
    def agent_failed(self, i: int, why: str) -> None: ...
    def running_behind(self, msg: str) -> None: ...


class Pacer:
    def __init__(self, world: PacedWorld) -> None:
        self.world = world
        self.next_second = 1.0  # boot seconds before t0, mission seconds after
        self.sim0: float | None = None  # the vehicles' clock when the run began (sim_s is counted from it)

    async def run(self) -> None:
        """Move time until the world stops."""
        raise NotImplementedError

    def start_at(self, t0: float) -> None:
        """The world announced the mission's start: the next second processed is t0."""
        self.next_second = t0

    def agent_failed(self, i: int, why: str) -> None:
        """Agent i is gone: a pacer that waits for agents stops waiting for it."""

    def _whole_second(self) -> None:
        second = self.next_second
        self.next_second += 1.0
        self.world.whole_second(second)


class FreePacer(Pacer):
    def __init__(self, world: PacedWorld, speedup: float, tick_hz: float) -> None:
        super().__init__(world)
        self.speedup, self.tick_hz = speedup, tick_hz
        self.pace = Pace(speedup)  # mission time lost to the bounded catch-up

    async def run(self) -> None:
        w = self.world
        self.sim0 = w.now
        period = 1.0 / self.tick_hz
        catchup = CATCHUP_TICKS * period
        last = time.perf_counter()
        next_tick = last + period
        while not w.stopping.is_set():
            delay = next_tick - time.perf_counter()
            await asyncio.sleep(max(0.0, delay))
            now = time.perf_counter()
            todo = min(now - last, catchup) * self.speedup  # bounded catch-up, as the runner
            if now - last > catchup and w.time.wall0 is not None and w.time.t0 is not None:
                self._fell_behind(now - last - catchup, w.now - w.time.t0, now - w.time.wall0)
            last = now
            while todo > 1e-9 and not w.stopping.is_set():
                todo = self._advance(todo)
                w.relay.pump()
                await asyncio.sleep(0)  # let datagrams and MQTT messages in between chunks
            next_tick = max(next_tick + period, now - period)

    def _advance(self, sim_s: float) -> float:
        """Advance up to `sim_s` (stopping at the next whole second); returns what is left."""
        w = self.world
        step = min(sim_s, CHUNK_S, self.next_second - w.now)
        if step > 1e-9:
            w.vehicles.advance(step)
            sim_s -= step
        if w.now >= self.next_second - 1e-9:
            self._whole_second()
        return sim_s

    def _fell_behind(self, lost_wall_s: float, mission_s: float, mission_wall_s: float) -> None:
        """The mission lost wall time to the bounded catch-up: say so once (`Pace`)."""
        self.pace.lose(lost_wall_s)
        msg = self.pace.notice(mission_s, mission_wall_s)
        if msg is not None:
            self.world.running_behind(msg)


class FollowPacer(Pacer):
    async def run(self) -> None:
        """Process each whole second once every live vehicle has reached it (their clocks,
        not ours), and pump the relay between."""
        w = self.world
        assert isinstance(w.vehicles, ExternalVehicles)
        changed = w.vehicles.changed
        said = -math.inf
        joined = False
        log.info("waiting for the vehicles' telemetry on %s", w.vehicles.describe())
        while not w.stopping.is_set():
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(FOLLOW_POLL_S):
                    await changed.wait()
            changed.clear()
            now = w.now
            if not math.isfinite(now):
                if time.monotonic() - said >= 10.0:
                    said = time.monotonic()
                    log.info("no vehicle streams its position yet: %s", ", ".join(w.not_ready()))
                continue
            if not joined:  # the vehicles may have been running for a while: start from their second
                joined = True
                self.sim0 = now
                self.next_second = max(1.0, float(math.ceil(now)))
            while self.next_second <= now + 1e-9 and not w.stopping.is_set():
                self._whole_second()
                w.relay.pump()
            w.relay.pump()


class LockstepPacer(Pacer):
    """Vehicle time waits for every member agent's answer to each telemetry sample and for
    the states of each instant; the speedup then paces only the start-up."""

    def __init__(self, world: PacedWorld, host: AutopilotHost, straggler_s: float, speedup: float) -> None:
        super().__init__(world)
        self.host, self.speedup = host, speedup
        self.barrier = Barrier(host.fleet, straggler_s)
        self._tick_due: float | None = None  # the boot second whose tick is not yet out
        self._tx_wait_since: float | None = None  # since when (wall) the tick waits for an instant's states
        self._instant_tup = world.time.tup_s  # T_up at the tick's second
        self._place_pending = False  # the start placement waits for the start second's answers

    def start_at(self, t0: float) -> None:
        super().start_at(t0)
        self._place_pending = True

    def agent_failed(self, i: int, why: str) -> None:
        self.barrier.fail(i, why)
        self.host.fleet.answers.set()  # the barrier stops waiting for it

    def state_held(self) -> None:
        """The relay holds a new state of an open instant: progress, so the wait for the rest
        restarts (`_instant_closed`), and the barrier wakes."""
        self._tx_wait_since = None
        self.host.fleet.answers.set()

    async def run(self) -> None:
        """One physics substep at a time, each once the barrier is met (`_settle`). Until
        every live vehicle's agent has joined (start-up), also paced at wall x speedup:
        arming and take-off are wall-clock command exchanges and need vehicle time to pass."""
        w = self.world
        self.sim0 = w.now
        dt = self.host.physics_dt
        wall0, sim0 = time.perf_counter(), w.now
        next_tick = float(math.floor(w.now + 1e-9) + 1)
        joined = False
        while not w.stopping.is_set():
            await self._settle()
            if w.stopping.is_set():
                break
            if self._place_pending:  # every answer to the start second's telemetry is in
                self._place_pending = False
                self._place_at_start()
            if joined and w.relay.idle:
                # Lockstep proper: the substeps up to the next one with work besides physics
                # (telemetry, the next second or tick) in one go, without a barrier check or
                # a trip through the event loop between them: nothing could arrive there that
                # the barrier waits for (issue 25.1).
                self.host.advance_substeps(QUIET_SUBSTEPS_MAX, min(self.next_second, next_tick))
            else:
                w.vehicles.advance(dt)
            if w.now >= self.next_second - 1e-9:
                self._instant_tup = w.time.tup_s  # the instants of this second follow T_up before its events
                self._whole_second()
            if w.now >= next_tick - 1e-9:  # every boot second, also those between the start and t0
                self._tick_due = next_tick
                next_tick += 1.0
            w.relay.pump()
            joined = joined or self.barrier.all_joined(w.alive().tolist())  # once all have joined, for good
            if joined:
                wall0, sim0 = time.perf_counter(), w.now
                await asyncio.sleep(0)
            else:
                await asyncio.sleep(max(0.0, (w.now - sim0) / self.speedup - (time.perf_counter() - wall0)))

    def _place_at_start(self) -> None:
        """The mission starts from the twin's start state exactly: every live vehicle at rest
        over its launch slot at the start altitude (the take-off before it ran on wall time)."""
        for i, a in enumerate(self.world.alive().tolist()):
            if a:
                self.host.place(i, (0.0, 0.0, -self.world.takeoff_alt))

    async def _settle(self) -> None:
        """The barrier: the tick of the last whole second is out (after its instant's states,
        relayed) and every member has answered its telemetry; stragglers are declared failed."""
        w, b, wake = self.world, self.barrier, self.host.fleet.answers
        while not w.stopping.is_set():
            wake.clear()
            wall = time.perf_counter()
            alive = w.alive().tolist()
            if self._tick_due is not None and self._instant_closed(alive, wall):
                w.outbox.publish_sticky(w.topics.tick, w.wire.json("tick", {"boot_s": self._tick_due}))
                self._tick_due = None
                b.restart(wall)  # the answers held for this tick can come only now
            owing = b.owing(alive)
            late = b.overdue(owing, wall)
            if late:  # answers may be unread behind a stall of this process: read them first
                await asyncio.sleep(0)
                owing = b.owing(alive)
                late = b.overdue(owing, time.perf_counter())
            if late and w.agents_working is not None and w.agents_working(late):
                b.restart(time.perf_counter())  # still computing: a starved machine, not a straggler
                late = []
            for i in late:
                w.agent_failed(i, f"no answer to its telemetry for {b.straggler_s:g} s")
            if late:  # a failed agent owes nothing any more
                owing = b.owing(alive)
            if self._tick_due is None and not owing:
                return
            left = b.wait_left(owing, wall)
            if self._tick_due is not None:
                left = min(left, 0.5 * b.straggler_s)
            # Waiting only for answers: wake once the last of them is in, not at each one.
            self.host.fleet.awaited = set(owing) if self._tick_due is None else None
            try:
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(left):
                        await wake.wait()
            finally:
                self.host.fleet.awaited = None

    def _instant_closed(self, alive: list[bool], wall: float) -> bool:
        """The tick's second has no instant open: none is due, or every member's state for it
        is in (then relayed), or the broker is down, or it waited half the straggler bound."""
        assert self._tick_due is not None
        t0 = self.world.time.t0
        if t0 is None or self._tick_due < t0 - 1e-6:
            return True
        relay = self.world.relay
        k = float(round(self._tick_due - t0))
        if k % self._instant_tup != 0 and not relay.holds(k):
            return True
        missing = set(self.barrier.members(alive)) - relay.held_senders(k)
        if missing and self.world.outbox.connected:
            if self._tx_wait_since is None:
                self._tx_wait_since = wall
            if wall - self._tx_wait_since < 0.5 * self.barrier.straggler_s:
                return False
            log.warning("lockstep: instant %d closed without the states of %s", int(k), sorted(missing))
        self._tx_wait_since = None
        relay.relay_instant(k)
        return True
