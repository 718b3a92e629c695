"""Batched guidance: turn each vehicle's active target into an acceleration command.

Every vehicle has one guidance *kind* and a target vector. They live in numpy arrays that
the per-vehicle state machines write at events (a setpoint arrives, a mode changes), and
the fleet reads them once per physics substep, so one batched call of the shared
controllers (`goto_accel`, `velocity_tracking_accel`, in their numpy copies: the same bits)
serves all N vehicles. Per-vehicle speed/acceleration limits are (N, 1) arrays: the
controllers broadcast them.
"""

from __future__ import annotations

import enum
from collections.abc import Callable

import numpy as np

from plmarl_sitl.model.vehicle import clip_norm_np, goto_accel_np, velocity_tracking_accel_np

# Position and velocity loops: a multirotor's position controller settles in about a second.
TIME_CONST_S = 0.5


class Kind(enum.IntEnum):
    IDLE = 0  # on the ground, motors idle or off: no acceleration
    ACCEL = 1  # external acceleration setpoint (net, gravity compensated)
    VELOCITY = 2  # track a velocity
    POSITION = 3  # fly to a point and stop there (hold, takeoff, position setpoints)
    LAND = 4  # hold x/y, descend at `descent` m/s
    FALL = 5  # motors off in the air (forced disarm, node failure)
    # A landing or fall reached the ground this substep and the airframe stopped (set by the
    # fleet's ground contact, after the physics); the vehicle then disarms and goes IDLE.
    TOUCHDOWN = 6


# Kinds as plain ints for the per-substep numpy tests: `Kind.X` costs ~0.3 us each, and numpy
# comparing an array with an enum member looks up a dozen dunders on the enum class (each a
# failed `EnumType.__getattr__`: 26 per `accel` call, a fifth of the fleet's physics, session 18).
_IDLE, _ACCEL, _VELOCITY, _POSITION, _LAND, _FALL, _TOUCHDOWN = (
    int(k) for k in (Kind.IDLE, Kind.ACCEL, Kind.VELOCITY, Kind.POSITION, Kind.LAND, Kind.FALL, Kind.TOUCHDOWN))


class Guidance:
    """Targets of N vehicles; `accel()` evaluates them all in one batched call."""

    def __init__(self, n: int) -> None:
        self.kind = np.zeros(n, dtype=np.int64)
        self.target = np.zeros((n, 3), dtype=np.float64)
        self.max_speed = np.ones((n, 1), dtype=np.float64)
        self.max_accel = np.ones((n, 1), dtype=np.float64)
        self.descent = np.zeros(n, dtype=np.float64)
        # Linear drag on an acceleration setpoint, 1/s (the personality's accel_drag_per_s):
        # PX4 feeds an acceleration-only setpoint forward with no velocity loop around it, so
        # the airframe's drag slows the vehicle (SIH: SIH_KDV / SIH_MASS = 1 /s).
        self.drag = np.zeros(n, dtype=np.float64)

    def set(self, i: int, kind: Kind, target: tuple[float, float, float] | None = None) -> None:
        self.kind[i] = kind
        if target is not None:
            self.target[i] = target

    def accel(self, pos: np.ndarray, vel: np.ndarray, fall_accel: float) -> np.ndarray:
        """(N, 3) acceleration commands for the current (N, 3) float64 states: the shared
        controllers in their numpy copies (`goto_accel_np`, ...; the same bits as the torch
        ones, tests/emulator/test_guidance_fast.py), a few microseconds a call where the
        torch ones cost ~0.1 ms a substep of a take-off (issue 25.1)."""
        fast = self.accel_setpoints_only(vel)
        if fast is not None:
            return fast
        kind, target, ms, ma = self.kind, self.target, self.max_speed, self.max_accel
        present = set(np.unique(kind).tolist())
        out = np.zeros_like(pos)
        if _ACCEL in present:
            a = clip_norm_np(target, ma)
            if self.drag.any():
                a = a - self.drag[:, None] * vel
            out = np.where((kind == _ACCEL)[:, None], a, out)
        if _VELOCITY in present:
            a = velocity_tracking_accel_np(vel, clip_norm_np(target, ms), ma, TIME_CONST_S)
            out = np.where((kind == _VELOCITY)[:, None], a, out)
        if _POSITION in present:
            a = goto_accel_np(pos, vel, target, ms, ma, TIME_CONST_S)
            out = np.where((kind == _POSITION)[:, None], a, out)
        if _LAND in present:
            v_xy = clip_norm_np((target[:, :2] - pos[:, :2]) / TIME_CONST_S, ms)
            v_des = np.concatenate([v_xy, self.descent[:, None]], axis=-1)
            a = velocity_tracking_accel_np(vel, v_des, ma, TIME_CONST_S)
            out = np.where((kind == _LAND)[:, None], a, out)
        if _FALL in present:
            down = np.zeros_like(pos)
            down[:, 2] = fall_accel
            out = np.where((kind == _FALL)[:, None], down, out)
        return out

    def accel_setpoints_only(self, vel: np.ndarray) -> np.ndarray | None:
        """The common case of a flying swarm, in numpy: every vehicle flies an
        acceleration setpoint clearly inside its limit, or has no command (zero). `accel`
        would return the setpoint times a scale factor of exactly 1.0 there (`clip_norm`),
        and +0.0 elsewhere: the same bits (tests/emulator/test_host.py). None otherwise."""
        command = self.setpoints_only_command()
        return None if command is None else command(vel)

    def setpoints_only_command(self) -> Callable[[np.ndarray], np.ndarray] | None:
        """`accel_setpoints_only` as a function of the velocity, its tests done once: for
        the substeps of one `Fleet.step_many`, between which nothing can change a kind, a
        target or a limit, only the velocity (under drag). None where it would be None."""
        kind = self.kind
        accel = kind == _ACCEL
        if not (accel | (kind == _IDLE) | (kind == _TOUCHDOWN)).all():
            return None
        target = self.target
        sq = (target * target).sum(-1)
        limit = self.max_accel[:, 0] * (1.0 - 1e-9)  # far outside a norm's round-off
        if not (np.isfinite(sq).all() and (sq[accel] <= (limit * limit)[accel]).all()):
            return None
        flying = accel[:, None]
        if self.drag.any():
            drag = self.drag[:, None]
            return lambda vel: np.where(flying, target - drag * vel, 0.0)
        acc = np.where(flying, target, 0.0)
        return lambda _vel: acc
