"""The fleet: the batched state of a host's N vehicles, the one object its vehicles share.

Everything per vehicle that is stepped or scanned for all vehicles at once lives here, in
arrays indexed by vehicle: the sim clock, the point-mass state, the guidance targets, the
setpoint-stream deadlines, which vehicles need their state machine run every substep, and
the telemetry schedule. The host owns the fleet and steps it; each `Vehicle` writes its own
row at events (a setpoint arrives, a mode changes) and reads it for telemetry. Vehicles
depend on the fleet, not on the host.

All vehicles are stepped in one batched call of the shared point-mass dynamics
(`plmarl_sitl.model.vehicle.step_point_mass`, float64, shape (N, 3)), in its numpy copy
`step_point_mass_np`: the same bits.
"""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Mapping

import numpy as np
import torch

from plmarl_sitl.model.vehicle import (
    Limits,
    free_flight_steps,
    free_flight_steps_under,
    step_point_mass_np,
)
from plmarl_sitl.sitl.autopilot.boot import Boot
from plmarl_sitl.sitl.autopilot.guidance import Guidance, Kind
from plmarl_sitl.sitl.autopilot.schedule import STREAM_PHASES, Scheduler

ON_GROUND_ALT_M = 0.05
# Kinds that end at ground contact; a vehicle flying one is always watched.
_ENDS_ON_GROUND = (Kind.LAND, Kind.FALL)
# Enum members as module constants: `Kind.X` is a class attribute lookup through the enum
# machinery (~0.3 us), and the per-substep loops use them for every watched vehicle.
_LAND, _FALL, _TOUCHDOWN = int(Kind.LAND), int(Kind.FALL), int(Kind.TOUCHDOWN)  # ints: see guidance.py


class Fleet:
    """State of `count` vehicles; vehicle i owns row i of every array.

    `rates` are the telemetry streams every vehicle starts with (message id -> Hz of sim time);
    `boot` the start-up stages all vehicles go through together (default: ready at once).
    """

    def __init__(self, count: int, limits: Limits, rates: Mapping[int, float], boot: Boot | None = None,
                 stream_phases: int = STREAM_PHASES) -> None:
        self.limits = limits
        self.boot = boot or Boot(None)
        self.now = 0.0  # sim seconds since boot
        self.unix_at_boot = time.time()
        self.guidance = Guidance(count)
        self.pos = torch.zeros(count, 3, dtype=torch.float64)
        self.vel = torch.zeros(count, 3, dtype=torch.float64)
        self.acc = torch.zeros(count, 3, dtype=torch.float64)
        self._refresh_views()
        self.sp_deadline = np.full(count, np.inf)  # sim time each vehicle's setpoint stream times out
        self._watched: dict[int, None] = {}  # insertion-ordered set
        self.gps_lost: set[int] = set()  # vehicles whose GPS is dark (their navigation reacts as time goes on)
        self.default_rates = dict(rates)
        self.streams = Scheduler(stream_phases)
        # Lockstep (`sitl.lockstep`): the time_boot_ms of the last LOCAL_POSITION_NED each
        # vehicle sent, and of the telemetry its last setpoint answered (-1: none yet).
        self.telemetry_ms = np.full(count, -1, dtype=np.int64)
        self.answered_ms = np.full(count, -1, dtype=np.int64)
        self.answers = asyncio.Event()  # set when a stamped setpoint arrives (see `answered`)
        self.answered_wall = -math.inf  # perf_counter s of the latest stamped setpoint (the barrier's progress)
        # The vehicles a lockstep world is waiting for (None: wake on every answer). Twenty
        # answers trickle in per telemetry round; waking the barrier for each one cost the
        # world's loop a full barrier check per answer instead of one per round (issue 25).
        self.awaited: set[int] | None = None
        for i in range(count):
            for msgid, hz in self.default_rates.items():
                self.streams.set_rate(i, msgid, hz, 0.0)

    def answered(self, i: int, telemetry_ms: int) -> None:
        """Vehicle i got a setpoint stamped with the telemetry time it answers (lockstep):
        wake the barrier once the last awaited vehicle has answered."""
        self.answered_ms[i] = telemetry_ms
        self.answered_wall = time.perf_counter()
        awaited = self.awaited
        if awaited is not None:
            awaited.discard(i)
            if awaited:
                return
        self.answers.set()

    def unix_time_s(self) -> float:
        return self.unix_at_boot + self.now

    # ------------------------------------------------------------------ one vehicle's row
    def altitude(self, i: int) -> float:
        return -float(self.pos_np[i, 2])

    def on_ground(self, i: int) -> bool:
        v = self.vel_np[i]
        vx, vy, vz = float(v[0]), float(v[1]), float(v[2])
        return self.altitude(i) <= ON_GROUND_ALT_M and abs(vz) < 0.2 and math.hypot(vx, vy) < 0.5

    def guide(self, i: int, kind: Kind, target: tuple[float, float, float] | None = None, *, watch: bool = False) -> None:
        """Give vehicle i a guidance kind (and target); `watch`: run its state machine every
        substep (as landings and falls always are) until it says it is idle."""
        self.guidance.set(i, kind, target)
        if watch or kind in _ENDS_ON_GROUND:
            self._watched[i] = None

    def set_deadline(self, i: int, t: float) -> None:
        """Sim time vehicle i's setpoint stream times out (inf: no timeout armed)."""
        self.sp_deadline[i] = t

    # ------------------------------------------------------------------ all vehicles
    def step(self, h: float) -> None:
        """Physics for `h` seconds, then ground contact (see `_ground_contact`)."""
        self._integrate(h)
        self.now += h
        if self._watched:
            self._ground_contact()

    def step_many(self, h: float, count: int) -> None:
        """`count` substeps of `h` with nothing between them (the host's quiet substeps): one
        call of the multi-step free flight when the whole swarm flies undisturbed, else
        `step` after `step`. The same bits either way."""
        if count > 1 and not self._watched:
            stepped = self._free_steps(h, count)
            if stepped is not None:
                self._set_state(*stepped)
                for _ in range(count):
                    self.now += h  # the clock's sum, substep by substep
                return
        for _ in range(count):
            self.step(h)

    def _free_steps(self, h: float, count: int) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """(pos, vel, acc) after `count` free-flight substeps in one call, or None."""
        g = self.guidance
        command = g.setpoints_only_command()  # tested once for all `count` substeps
        if command is None:
            return None
        if g.drag.any():  # PX4: the command is recomputed from each substep's velocity
            return free_flight_steps_under(self.pos_np, self.vel_np, command, h, count, self.limits)
        acc = command(self.vel_np)  # no drag: the same in every substep
        stepped = free_flight_steps(self.pos_np, self.vel_np, acc, h, count, self.limits)
        return None if stepped is None else (stepped[0], stepped[1], acc)

    def _set_state(self, pos: np.ndarray, vel: np.ndarray, acc: np.ndarray) -> None:
        self.pos_np, self.vel_np, self.acc_np = pos, vel, acc
        self.pos, self.vel, self.acc = torch.from_numpy(pos), torch.from_numpy(vel), torch.from_numpy(acc)

    def _integrate(self, h: float) -> None:
        # The batched guidance's command (a flying swarm's setpoints taken as they are, its
        # first test), then the numpy copy of the shared point-mass step: free flight in a
        # few numpy calls, else its event solver (a vehicle coasting at V_max, lifting off
        # the floor), the same bits as `step_point_mass` at a fraction of its per-call cost
        # (issue 25.1).
        acc = self.guidance.accel(self.pos_np, self.vel_np, self.limits.max_accel)
        self._set_state(*step_point_mass_np(self.pos_np, self.vel_np, acc, h, self.limits), acc)

    def _ground_contact(self) -> None:
        """A landing or a fall that reached the ground stops there: the kind becomes TOUCHDOWN,
        which the vehicle's state machine turns into disarmed and idle.

        The floor of the dynamics only removes vertical velocity, and a wreck (or a landing
        drifting under 0.5 m/s) would slide on for ever. A fall ends where the airframe hits
        the ground, at whatever speed; a landing once it has settled (`on_ground`).
        """
        kind = self.guidance.kind
        landing, falling = kind == _LAND, kind == _FALL
        if not (landing.any() or falling.any()):  # a take-off (watched too) touches nothing: one numpy test
            return
        for i in self._watched:
            if (landing[i] and self.on_ground(i)) or (falling[i] and self.altitude(i) <= ON_GROUND_ALT_M):
                self.vel_np[i] = 0.0  # a view of the velocity tensor
                kind[i] = _TOUCHDOWN

    def watched(self) -> list[int]:
        return list(self._watched)

    def unwatch(self, i: int) -> None:
        del self._watched[i]

    def quiet_substeps(self, h: float, most: int, stop_at: float) -> int:
        """How many substeps of `h` (1 to `most`) can run as one: every one before the last
        has nothing to do but physics (no vehicle watched, no GPS loss, no boot event, no
        setpoint deadline passing, no telemetry due), and the clock reaches `stop_at` at
        the last at the earliest. Sums the clock as `step` does, so the substep it stops at
        is the one the substep-by-substep loop would act at."""
        if most <= 1 or self._watched or self.gps_lost or self.boot.timeline is not None:
            return 1
        deadline = float(self.sp_deadline.min())
        due = self.streams.next_due()
        t = self.now
        for count in range(1, most + 1):
            t += h
            if t >= stop_at - 1e-9 or deadline < t or due <= t + 1e-9:
                return count
        return most

    def setpoints_lost(self) -> list[int]:
        """Vehicles whose setpoint deadline has passed (one numpy call when none has)."""
        if self.sp_deadline.min() < self.now:
            return np.flatnonzero(self.sp_deadline < self.now).tolist()
        return []

    def _refresh_views(self) -> None:
        # Zero-copy numpy views for the per-vehicle Python code (telemetry, state machines).
        self.pos_np = self.pos.numpy()
        self.vel_np = self.vel.numpy()
        self.acc_np = self.acc.numpy()
