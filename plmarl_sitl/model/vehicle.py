"""Point-mass vehicle dynamics, shared by the digital twin and the autopilot emulator.

State is position and velocity in a local NED frame (x north, y east, z down), as tensors
with any number of leading batch dimensions and a trailing dimension of 3. The command is a
net acceleration (gravity already compensated, as a PX4 acceleration setpoint means).

Integration is exact for a piecewise-constant command at any step size: inside a step the
motion is ballistic (p + v t + a t^2 / 2) until an *event*, and events are solved in closed
form rather than detected after the fact:

* the speed reaches `max_speed`: from then on the vehicle coasts at that velocity for as
  long as the command would push the speed higher (a saturating speed limiter);
* the altitude reaches the band edge: vertical velocity becomes zero and the vertical
  command is ignored while it points out of the band.

Because the rules depend only on the current state and command, stepping once by `dt` or
k times by `dt / k` gives the same result (the semigroup property the tests check). Limits
can therefore never be exceeded, whatever the step size. Drag is not modelled: the point
mass is meant to follow commanded accelerations, as a well-tuned multirotor does.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from plmarl_sitl.config import VehicleModel

_TIME_TOL = 1e-7  # s: roots closer to "now" than this are the event we are sitting on
_COAST_TOL = 1e-6  # s: at V_max, a dip below the limit shorter than this counts as pushing
_MAX_EVENTS = 5  # speed, wall, speed again after the wall, plus numerical slack
# Up to this many vehicles per call, per-op overhead dominates and a step where nobody can
# meet a limit takes a ballistic shortcut (the autopilot host's 20 vehicles at 50 Hz). Big
# twin batches rarely qualify as a whole, so they skip the check.
_FREE_FLIGHT_MAX_BATCH = 256


@dataclass(frozen=True)
class Limits:
    """Kinematic limits as the dynamics see them. Altitudes are positive up (AGL)."""

    max_speed: float
    max_accel: float
    alt_min: float
    alt_max: float

    @classmethod
    def band(cls, model: VehicleModel) -> Limits:
        """The mission band used by the twin: the vehicle never leaves [min_alt, max_alt]."""
        return cls(model.max_speed_mps, model.max_accel_mps2, model.min_alt_m, model.max_alt_m)

    @classmethod
    def ground_to_ceiling(cls, model: VehicleModel) -> Limits:
        """What an autopilot flies in: the ground is a floor at 0 m, the ceiling is max_alt."""
        return cls(model.max_speed_mps, model.max_accel_mps2, 0.0, model.max_alt_m)


def clip_norm(x: torch.Tensor, max_norm: float) -> torch.Tensor:
    """Scale vectors (last dim) down to at most `max_norm`; NaN-free for zero vectors."""
    norm = torch.linalg.vector_norm(x, dim=-1, keepdim=True)
    scale = torch.clamp(max_norm / torch.clamp(norm, min=1e-12), max=1.0)
    return x * scale


def _first_upcrossing(half_c: torch.Tensor, b: torch.Tensor, d: torch.Tensor, min_t: float = _TIME_TOL) -> torch.Tensor:
    """Smallest t > min_t where f(t) = half_c t^2 + b t + d crosses zero *upward*, else +inf.

    Only up-crossings are limit events: a state that starts a hair outside a limit
    through float round-off and is moving back in must not "hit" it again (that would
    fire an event every few nanoseconds and stall the step).
    """
    inf = torch.full_like(b, float("inf"))
    quad = half_c.abs() > 1e-12
    # Linear case: f' = b must be positive.
    safe_b = torch.where(b.abs() > 1e-12, b, torch.ones_like(b))
    lin = torch.where((b > 1e-12) & (-d / safe_b > min_t), -d / safe_b, inf)
    # Quadratic case: of the two roots, the up-crossing is where f' = 2 half_c t + b > 0.
    disc = b * b - 4.0 * half_c * d
    sq = torch.sqrt(torch.clamp(disc, min=0.0))
    # Roots as q / half_c and d / q with q = -(b + sign(b) sq) / 2: the textbook
    # (-b +- sq) / (2 half_c) cancels catastrophically when half_c is tiny (float32, a
    # 1e-9 m/s^2 vertical command: sq rounds to |b| and a root at t = 0 put a vehicle
    # 1 m above the floor onto it).
    q = -0.5 * (b + torch.where(b >= 0, sq, -sq))
    safe_c = torch.where(quad, half_c, torch.ones_like(half_c))
    safe_q = torch.where(q != 0, q, torch.ones_like(q))
    r1 = q / safe_c
    r2 = torch.where(q != 0, d / safe_q, r1)
    r1 = torch.where((r1 > min_t) & (2.0 * half_c * r1 + b > 0), r1, inf)
    r2 = torch.where((r2 > min_t) & (2.0 * half_c * r2 + b > 0), r2, inf)
    return torch.where(quad, torch.where(disc >= 0, torch.minimum(r1, r2), inf), lin)


def _wall_tol(x: torch.Tensor, lim: Limits) -> float:
    """How close to a band edge counts as "on" it: a few ulps of the altitude's dtype."""
    return 16.0 * torch.finfo(x.dtype).eps * max(1.0, lim.alt_max)


def _speed_snap(x: torch.Tensor) -> float:
    """Relative distance below V_max that counts as "at" it: a few ulps of the dtype.
    (Looser would start coasting before a real dip below the limit has ended.)"""
    return 16.0 * torch.finfo(x.dtype).eps


def _effective_accel(
    pos: torch.Tensor, vel: torch.Tensor, acc: torch.Tensor, lim: Limits
) -> torch.Tensor:
    """The command with what the limits forbid removed: no vertical push into a band edge
    the vehicle rests on, and nothing while at V_max that would raise the speed."""
    alt = -pos[..., 2]
    v_up = -vel[..., 2]
    tol = _wall_tol(pos, lim)
    v_tol = _speed_snap(vel) * lim.max_speed  # a vertical speed this small is resting
    on_floor = (alt <= lim.alt_min + tol) & (v_up <= v_tol)
    on_ceiling = (alt >= lim.alt_max - tol) & (v_up >= -v_tol)
    acc = acc.clone()
    # NED: pushing down (into the floor) is acc_z > 0, up (into the ceiling) is acc_z < 0.
    acc[..., 2] = torch.where(on_floor, torch.clamp(acc[..., 2], max=0.0), acc[..., 2])
    acc[..., 2] = torch.where(on_ceiling, torch.clamp(acc[..., 2], min=0.0), acc[..., 2])
    # At V_max (see _snap_speed) the command keeps raising the speed unless it first
    # dips below the limit for longer than _COAST_TOL: |v + a t| < V for 0 < t < -2 v.a / |a|^2.
    at_limit = (vel * vel).sum(-1) >= (lim.max_speed * (1.0 - _speed_snap(vel))) ** 2
    pushing = (vel * acc).sum(-1) >= -0.5 * _COAST_TOL * (acc * acc).sum(-1)
    return acc * (~(at_limit & pushing)).unsqueeze(-1).to(acc.dtype)


def _snap_walls(pos: torch.Tensor, vel: torch.Tensor, lim: Limits) -> tuple[torch.Tensor, torch.Tensor]:
    """A vehicle on a band edge cannot keep moving through it: put it exactly on the edge
    and zero that vertical speed (what the wall event would have done)."""
    alt, v_up = -pos[..., 2], -vel[..., 2]
    tol = _wall_tol(pos, lim)
    low = (alt <= lim.alt_min + tol) & (v_up < 0)
    high = (alt >= lim.alt_max - tol) & (v_up > 0)
    stopped = low | high
    if not bool(stopped.any()):
        return pos, vel
    pos, vel = pos.clone(), vel.clone()
    pos[..., 2] = torch.where(low, -lim.alt_min, torch.where(high, -lim.alt_max, pos[..., 2]))
    vel[..., 2] = torch.where(stopped, torch.zeros_like(v_up), vel[..., 2])
    return pos, vel


def _snap_speed(vel: torch.Tensor, lim: Limits, force: torch.Tensor | None = None) -> torch.Tensor:
    """Put speeds within a few ulps of V_max (or where `force`) exactly on it."""
    speed = torch.linalg.vector_norm(vel, dim=-1, keepdim=True)
    near = speed >= lim.max_speed * (1.0 - _speed_snap(vel))
    if force is not None:
        near = near | force.unsqueeze(-1)
    return torch.where(near, vel * (lim.max_speed / torch.clamp(speed, min=1e-12)), vel)


def _event_times(
    pos: torch.Tensor, vel: torch.Tensor, a: torch.Tensor, lim: Limits, min_t: float
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(t_speed, t_ceiling, t_floor): first up-crossing after min_t of each limit.

    Three quadratics solved in one batched call (small-tensor ops cost per call):
    speed:   |v + a t|^2 - V^2 = |a|^2 t^2 + 2 (v.a) t + |v|^2 - V^2 rises through 0
    ceiling: h + w t + c t^2 / 2 - alt_max rises through 0 (altitude positive up)
    floor:   alt_min - (h + w t + c t^2 / 2) rises through 0
    """
    h, w, c = -pos[..., 2], -vel[..., 2], -a[..., 2]
    half_c = torch.stack([(a * a).sum(-1), 0.5 * c, -0.5 * c])
    lin = torch.stack([2.0 * (vel * a).sum(-1), w, -w])
    const = torch.stack([(vel * vel).sum(-1) - lim.max_speed**2, h - lim.alt_max, lim.alt_min - h])
    t_speed, t_ceil, t_floor = _first_upcrossing(half_c, lin, const, min_t)
    return t_speed, t_ceil, t_floor


def _advance(
    pos: torch.Tensor, vel: torch.Tensor, acc: torch.Tensor, t_left: torch.Tensor, lim: Limits
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Move (M, 3) states ballistically up to the first event or the end of the step."""
    pos, vel = _snap_walls(pos, vel, lim)
    vel = _snap_speed(vel, lim)
    a = _effective_accel(pos, vel, acc, lim)
    # A limit reached within _TIME_TOL is reached now: too close to solve for as an
    # event, so put the vehicle on it and let the constrained command take over.
    # Crossings in (-tol, tol] are "now" (a hair in the past is round-off, not history).
    t_speed, t_ceil, t_floor = _event_times(pos, vel, a, lim, -_TIME_TOL)
    now_speed = t_speed <= _TIME_TOL
    now_wall = torch.minimum(t_ceil, t_floor) <= _TIME_TOL
    if bool(now_speed.any()) or bool(now_wall.any()):
        if bool(now_wall.any()):
            edge = torch.where(t_ceil <= t_floor, torch.full_like(t_ceil, -lim.alt_max), torch.full_like(t_ceil, -lim.alt_min))
            pos = pos.clone()
            vel = vel.clone()
            pos[..., 2] = torch.where(now_wall, edge, pos[..., 2])
            vel[..., 2] = torch.where(now_wall, torch.zeros_like(edge), vel[..., 2])
        vel = _snap_speed(vel, lim, force=now_speed)
        a = _effective_accel(pos, vel, acc, lim)
        t_speed, t_ceil, t_floor = _event_times(pos, vel, a, lim, _TIME_TOL)
    t_wall = torch.minimum(t_ceil, t_floor)
    t = torch.minimum(t_left, torch.minimum(t_speed, t_wall))
    tt = t.unsqueeze(-1)
    pos = pos + vel * tt + 0.5 * a * tt * tt
    vel = vel + a * tt
    hit_wall = (t_wall <= t) & torch.isfinite(t_wall)
    if bool(hit_wall.any()):
        bound = torch.where(t_ceil <= t_floor, torch.full_like(t, lim.alt_max), torch.full_like(t, lim.alt_min))
        pos[..., 2] = torch.where(hit_wall, -bound, pos[..., 2])
        vel[..., 2] = torch.where(hit_wall, torch.zeros_like(t), vel[..., 2])
    hit_speed = (t_speed <= t) & torch.isfinite(t_speed)
    if bool(hit_speed.any()):
        vel = torch.where(hit_speed.unsqueeze(-1), clip_norm(vel, lim.max_speed), vel)
    return pos, vel, t_left - t


def _free_flight(
    pos: torch.Tensor, vel: torch.Tensor, acc: torch.Tensor, dt: float, lim: Limits
) -> tuple[torch.Tensor, torch.Tensor]:
    """(inside, resting), (M,) bool each. inside: the vehicle meets no limit during [0, dt]
    and is not sitting on one, with a margin far above the snapping tolerances. resting: it
    stands still on the floor and is pushed into it or not at all, so it stays put.

    Speed: |v + a t| <= |v| + |a| t, so |v| + |a| dt below V_max means no speed event.
    Altitude: h + w t + c t^2 / 2 stays within h -/+ (|w| dt + |c| dt^2 / 2).
    """
    margin = 1e3 * _wall_tol(pos, lim)
    speed = torch.linalg.vector_norm(vel, dim=-1)
    reach_v = speed + torch.linalg.vector_norm(acc, dim=-1) * dt
    alt = -pos[..., 2]
    reach_h = vel[..., 2].abs() * dt + 0.5 * acc[..., 2].abs() * dt * dt
    inside = (reach_v < lim.max_speed * (1.0 - 1e3 * _speed_snap(vel))) & (alt - reach_h > lim.alt_min + margin) & (
        alt + reach_h < lim.alt_max - margin
    )
    # Still means every component zero: a subnormal speed squares to 0 in the norm.
    still = (vel == 0).all(-1)
    resting = still & (acc[..., 0] == 0) & (acc[..., 1] == 0) & (acc[..., 2] >= 0) & (alt <= lim.alt_min)
    return inside, resting


def _free_flight_numpy(
    pos: torch.Tensor, vel: torch.Tensor, accel_cmd: torch.Tensor, dt: float, lim: Limits
) -> tuple[torch.Tensor, torch.Tensor] | None:
    """`free_flight_step` on float64 CPU tensors (views, no copies); None when it does not apply."""
    if (
        pos.dtype != torch.float64 or vel.dtype != torch.float64 or accel_cmd.dtype != torch.float64
        or pos.device.type != "cpu" or pos.requires_grad or vel.requires_grad or accel_cmd.requires_grad
    ):
        return None
    p = pos.detach().reshape(-1, 3).numpy()
    if p.shape[0] > _FREE_FLIGHT_MAX_BATCH:
        return None
    v = vel.detach().reshape(-1, 3).numpy()
    acc = accel_cmd.detach().reshape(-1, 3).numpy()
    if v.shape != p.shape or acc.shape != p.shape:
        return None
    out = free_flight_step(p, v, acc, dt, lim)
    return None if out is None else (torch.from_numpy(out[0]), torch.from_numpy(out[1]))


def free_flight_step(
    p: np.ndarray, v: np.ndarray, acc: np.ndarray, dt: float, lim: Limits
) -> tuple[np.ndarray, np.ndarray] | None:
    """The free-flight step of `step_point_mass` in numpy, bit for bit, on float64 (M, 3)
    arrays (position, velocity, command) that need none of its projections; None when it
    does not apply to every vehicle.

    A torch call on a (20, 3) tensor costs a few microseconds whatever it computes, and the
    autopilot emulator steps its fleet 50 times per simulated second: this path does the
    same IEEE operations in the same order with numpy's lower per-call cost. It applies
    only where every projection of the torch path is the identity: all finite, every
    command and velocity clearly inside its norm limit (torch's scale factor would be
    exactly 1.0), every altitude inside the band (the clamp returns it unchanged). The
    free-flight test is then the same inequalities (margins of 1e3 ulps, so a last-bit
    difference in a norm cannot matter; and at its boundary both paths agree anyway).
    tests/model/test_vehicle.py compares it with the torch path."""
    if len(p) and _clearly_inside(p, v, acc, dt, lim):  # the common substep: 6 numpy calls, not ~30
        dt = float(dt)  # `_ballistic` with an all-True mask (acc x 1.0 is acc)
        return p + v * dt + 0.5 * acc * dt * dt, v + acc * dt
    free, inside = _free_in_numpy(p, v, acc, dt, lim)
    if not free.all():
        return None
    return _ballistic(p, v, acc, inside, dt)


def _free_in_numpy(
    p: np.ndarray, v: np.ndarray, acc: np.ndarray, dt: float, lim: Limits
) -> tuple[np.ndarray, np.ndarray]:
    """(free, inside), (M,) bool each: `free_flight_step`'s conditions per vehicle (free: no
    projection of the torch path changes it and it is inside or resting, `_free_flight`)."""
    acc_sq = (acc * acc).sum(-1)
    vel_sq = (v * v).sum(-1)
    alt = -p[:, 2]
    inner = 1.0 - 1e-9  # far outside the round-off of a norm, far inside the limit
    with np.errstate(invalid="ignore"):  # NaN and inf compare False: not free
        plain = (np.isfinite(acc_sq) & np.isfinite(vel_sq) & np.isfinite(alt)
                 & (acc_sq <= (lim.max_accel * inner) ** 2) & (vel_sq <= (lim.max_speed * inner) ** 2)
                 & (alt >= lim.alt_min) & (alt <= lim.alt_max))
        dt = float(dt)
        margin = 1e3 * 16.0 * np.finfo(np.float64).eps * max(1.0, lim.alt_max)  # _free_flight's margin
        reach_v = np.sqrt(vel_sq) + np.sqrt(acc_sq) * dt
        reach_h = np.abs(v[:, 2]) * dt + 0.5 * np.abs(acc[:, 2]) * dt * dt
        inside = (reach_v < lim.max_speed * (1.0 - 1e3 * 16.0 * np.finfo(np.float64).eps)) & (
            alt - reach_h > lim.alt_min + margin) & (alt + reach_h < lim.alt_max - margin)
        still = (v == 0).all(-1)
        resting = still & (acc[:, 0] == 0) & (acc[:, 1] == 0) & (acc[:, 2] >= 0) & (alt <= lim.alt_min)
    return plain & (inside | resting), inside


def _ballistic(p: np.ndarray, v: np.ndarray, acc: np.ndarray, inside: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The torch path's ballistic update, operation for operation (a resting vehicle: no command)."""
    dt = float(dt)
    a = acc * inside[:, None].astype(np.float64)
    return p + v * dt + 0.5 * a * dt * dt, v + a * dt


_SQRT3 = 1.7320508075688774  # |x| <= sqrt(3) max |x_i|; rounded up, and the margins below are 1e-6


def _clearly_inside(p: np.ndarray, v: np.ndarray, acc: np.ndarray, dt: float, lim: Limits) -> bool:
    """A cheap sufficient condition for every vehicle being free and inside (`_free_in_numpy`):
    bounds from the largest components, a million times wider than the round-off, so that
    wherever it holds the exact test holds too (a NaN fails every comparison: the exact test
    decides). A hovering team (the common second) costs 6 numpy calls instead of ~25."""
    dt = float(dt)
    vmax, amax, vz, az = float(np.abs(v).max()), float(np.abs(acc).max()), float(np.abs(v[:, 2]).max()), float(np.abs(acc[:, 2]).max())
    alt_lo, alt_hi = float(-p[:, 2].max()), float(-p[:, 2].min())
    reach_h = vz * dt + 0.5 * az * dt * dt
    margin = 1e3 * 16.0 * np.finfo(np.float64).eps * max(1.0, lim.alt_max) + 1e-6
    return bool(_SQRT3 * (vmax + amax * dt) < lim.max_speed * (1.0 - 1e-6) and _SQRT3 * amax < lim.max_accel * (1.0 - 1e-6)
                and alt_lo - reach_h > lim.alt_min + margin and alt_hi + reach_h < lim.alt_max - margin)


def free_flight_steps(
    p: np.ndarray, v: np.ndarray, acc: np.ndarray, dt: float, count: int, lim: Limits
) -> tuple[np.ndarray, np.ndarray] | None:
    """`count` successive `free_flight_step` steps under one constant command, bit for bit,
    or None if any one of them would not apply (`free_flight_steps_under` with a command
    that does not depend on the velocity: an ArduPilot fleet between two telemetry samples)."""
    if count <= 1:
        return free_flight_step(p, v, acc, dt, lim) if count == 1 else (p, v)
    stepped = free_flight_steps_under(p, v, lambda _v: acc, dt, count, lim)
    return None if stepped is None else (stepped[0], stepped[1])


def free_flight_steps_under(
    p: np.ndarray, v: np.ndarray, command: Callable[[np.ndarray], np.ndarray | None], dt: float, count: int, lim: Limits
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """`count` successive `free_flight_step` steps under a command that depends on the
    velocity, `command(v)` recomputed at each substep (an acceleration setpoint less the
    airframe's linear drag, as the autopilot emulator's PX4 flies it), bit for bit; returns
    (position, velocity, the last substep's command), or None if `command` or any one
    step would not apply.

    The ballistic updates are done in sequence (the same operations, so the same bits as
    that many `free_flight_step` calls), then the free-flight test of every later substep in
    one vectorised pass over the stacked states and their commands, instead of a pass of
    ~30-45 numpy calls per substep (issue 25.1). A vehicle the first test holds still
    (resting) stays still, so one mask serves every substep; every later test must agree
    with it (the same vehicles inside)."""
    if p.shape[0] > _FREE_FLIGHT_MAX_BATCH:
        return None
    acc = command(v)
    if acc is None:
        return None
    # `_clearly_inside` (a sufficient condition, a million times wider than the round-off)
    # spares the exact test where it holds: then every vehicle is free and inside.
    clear = bool(len(p)) and _clearly_inside(p, v, acc, dt, lim)
    if clear:
        inside = np.ones(p.shape[0], dtype=bool)
    else:
        free, inside = _free_in_numpy(p, v, acc, dt, lim)
        if not free.all():
            return None
    if count <= 1:
        return (*_ballistic(p, v, acc, inside, dt), acc) if count == 1 else (p, v, acc)
    dt = float(dt)
    mask = inside[:, None].astype(np.float64)  # `_ballistic`'s mask
    ps, vs, accs = [], [], []
    for k in range(count):
        if k:
            acc = command(v)
            if acc is None:
                return None
            ps.append(p)
            vs.append(v)
            accs.append(acc)
        a = acc * mask
        p = p + v * dt + 0.5 * a * dt * dt
        v = v + a * dt
    ps, vs, accs = np.concatenate(ps), np.concatenate(vs), np.concatenate(accs)
    if clear and _clearly_inside(ps, vs, accs, dt, lim):
        return p, v, acc  # every later substep free and inside too, as the first
    later_free, later_inside = _free_in_numpy(ps, vs, accs, dt, lim)
    if not (later_free.all() and (later_inside.reshape(count - 1, -1) == inside).all()):
        return None
    return p, v, acc


def step_point_mass(
    pos: torch.Tensor,
    vel: torch.Tensor,
    accel_cmd: torch.Tensor,
    dt: float,
    lim: Limits,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Advance (pos, vel) by `dt` seconds under a constant acceleration command.

    The command is clipped to `max_accel` (Euclidean norm). Returns new (pos, vel).
    """
    shape = pos.shape
    fast = _free_flight_numpy(pos, vel, accel_cmd, dt, lim)
    if fast is not None:
        return fast[0].reshape(shape), fast[1].reshape(shape)
    acc = clip_norm(torch.nan_to_num(accel_cmd), lim.max_accel).reshape(-1, 3)
    # Start inside the limits: a state handed in slightly outside (e.g. float32 round-off
    # or a fresh spawn) is projected back so the event solver's preconditions hold.
    p = pos.reshape(-1, 3).clone()
    p[:, 2] = -torch.clamp(-p[:, 2], lim.alt_min, lim.alt_max)
    v = clip_norm(vel.reshape(-1, 3), lim.max_speed)
    t_left = torch.full(p.shape[:1], float(dt), dtype=p.dtype, device=p.device)
    if p.shape[0] <= _FREE_FLIGHT_MAX_BATCH:
        inside, resting = _free_flight(p, v, acc, float(dt), lim)
        if bool((inside | resting).all()):
            # No vehicle can reach a limit within this step: the event solver would find
            # no event and return exactly this ballistic update (same ops, same order;
            # a resting vehicle's command is what the floor removes).
            a = acc * inside.unsqueeze(-1).to(acc.dtype)
            tt = t_left.unsqueeze(-1)
            p = p + v * tt + 0.5 * a * tt * tt
            v = v + a * tt
            return p.reshape(shape), v.reshape(shape)
    p, v, t_left = _advance(p, v, acc, t_left, lim)
    # Only vehicles that met an event this step have time left: iterate on that subset.
    idx = torch.nonzero(t_left > _TIME_TOL).flatten()
    for _ in range(_MAX_EVENTS - 1):
        if idx.numel() == 0:
            break
        ps, vs, ts = _advance(p[idx], v[idx], acc[idx], t_left[idx], lim)
        p[idx], v[idx], t_left[idx] = ps, vs, ts
        idx = idx[ts > _TIME_TOL]
    if idx.numel():
        # More events than expected in one step (a numerically pathological state): finish
        # the step ballistically under the constrained command; the guard below clamps.
        p[idx], v[idx] = _snap_walls(p[idx], v[idx], lim)
        v[idx] = _snap_speed(v[idx], lim)
        a = _effective_accel(p[idx], v[idx], acc[idx], lim)
        tt = t_left[idx].unsqueeze(-1)
        p[idx] = p[idx] + v[idx] * tt + 0.5 * a * tt * tt
        v[idx] = v[idx] + a * tt
    # Round-off guard: the analytic solution already respects the limits.
    v = clip_norm(v, lim.max_speed)
    p[:, 2] = -torch.clamp(-p[:, 2], lim.alt_min, lim.alt_max)
    p, v = _snap_walls(p, v, lim)
    return p.reshape(shape), v.reshape(shape)


def velocity_tracking_accel(
    vel: torch.Tensor, vel_target: torch.Tensor, max_accel: float, time_const: float = 1.0
) -> torch.Tensor:
    """Acceleration that drives `vel` to `vel_target` with first-order lag `time_const`."""
    return clip_norm((vel_target - vel) / time_const, max_accel)


def goto_accel(
    pos: torch.Tensor,
    vel: torch.Tensor,
    target: torch.Tensor,
    max_speed: float,
    max_accel: float,
    time_const: float = 1.0,
) -> torch.Tensor:
    """Acceleration that flies to `target` and stops there.

    The desired velocity points at the target with the largest speed from which the
    vehicle can still brake at half its acceleration limit, so it does not overshoot.
    """
    delta = target - pos
    dist = torch.linalg.vector_norm(delta, dim=-1, keepdim=True)
    brake_speed = torch.sqrt(2.0 * 0.5 * max_accel * dist)
    speed = torch.minimum(brake_speed, torch.clamp(dist / time_const, max=max_speed))
    v_des = delta / torch.clamp(dist, min=1e-9) * speed
    return velocity_tracking_accel(vel, v_des, max_accel, time_const)


# ---------------------------------------------------------------------------------------
# `step_point_mass` in numpy, operation for operation (the autopilot emulator's fleet).
#
# Why: the emulator steps its (N, 3) fleet 50 times per simulated second, and whenever one
# vehicle is not in free flight (coasting at V_max towards its goal, lifting off the floor)
# the torch event solver ran on the whole batch: ~120 small torch calls, ~0.8 ms a substep,
# 782 substeps of a scale_20 mission (issue 25.1). The same IEEE operations in numpy cost a
# fraction of that. Where numpy and torch are not bit for bit the same on every input, the
# operation stays torch's, on an array of the same shape: the square root (this torch's
# vectorised sqrt is not correctly rounded: 0.7 % of random inputs differ from numpy's by
# an ulp), the Euclidean norm (from 8 rows on torch's kernel rounds differently from a sum
# of squares), and the minimum/clamp whose ties between +0.0 and -0.0 torch breaks by
# element position (vector body or scalar tail). `scalar / tensor` is torch's
# `reciprocal() * scalar`, two roundings: written so here. tests/model/test_vehicle_numpy.py
# compares both on edge states.


def _t(x: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(x)


def _norm_np(x: np.ndarray, keepdim: bool = False) -> np.ndarray:
    return torch.linalg.vector_norm(_t(x), dim=-1, keepdim=keepdim).numpy()


def _clamp_np(x: np.ndarray, lo: float | None = None, hi: float | None = None) -> np.ndarray:
    return torch.clamp(_t(x), lo, hi).numpy()


def _minimum_np(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return torch.minimum(_t(a), _t(b)).numpy()


def _rdiv(scalar: float, x: np.ndarray) -> np.ndarray:
    """torch's `scalar / x`: `x.reciprocal() * scalar`."""
    return (1.0 / x) * scalar


def clip_norm_np(x: np.ndarray, max_norm: float | np.ndarray) -> np.ndarray:
    """`clip_norm` on a float64 array, bit for bit (max_norm a float or an array that broadcasts)."""
    norm = _norm_np(x, keepdim=True)
    floor = np.maximum(norm, 1e-12)  # clamp(min=1e-12): no signed-zero tie, NaN kept as torch does
    ratio = _rdiv(max_norm, floor) if isinstance(max_norm, float) else max_norm / floor
    return x * np.minimum(ratio, 1.0)


_F64_EPS = float(np.finfo(np.float64).eps)


def _first_upcrossing_np(half_c: np.ndarray, b: np.ndarray, d: np.ndarray, min_t: float = _TIME_TOL) -> np.ndarray:
    inf = np.full_like(b, float("inf"))
    quad = np.abs(half_c) > 1e-12
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        safe_b = np.where(np.abs(b) > 1e-12, b, np.ones_like(b))
        lin = np.where((b > 1e-12) & (-d / safe_b > min_t), -d / safe_b, inf)
        disc = b * b - 4.0 * half_c * d
        sq = torch.sqrt(torch.clamp(_t(disc), min=0.0)).numpy()
        q = -0.5 * (b + np.where(b >= 0, sq, -sq))
        safe_c = np.where(quad, half_c, np.ones_like(half_c))
        safe_q = np.where(q != 0, q, np.ones_like(q))
        r1 = q / safe_c
        r2 = np.where(q != 0, d / safe_q, r1)
        r1 = np.where((r1 > min_t) & (2.0 * half_c * r1 + b > 0), r1, inf)
        r2 = np.where((r2 > min_t) & (2.0 * half_c * r2 + b > 0), r2, inf)
    return np.where(quad, np.where(disc >= 0, _minimum_np(r1, r2), inf), lin)


def _effective_accel_np(pos: np.ndarray, vel: np.ndarray, acc: np.ndarray, lim: Limits) -> np.ndarray:
    alt = -pos[..., 2]
    v_up = -vel[..., 2]
    tol = 16.0 * _F64_EPS * max(1.0, lim.alt_max)
    v_tol = 16.0 * _F64_EPS * lim.max_speed
    on_floor = (alt <= lim.alt_min + tol) & (v_up <= v_tol)
    on_ceiling = (alt >= lim.alt_max - tol) & (v_up >= -v_tol)
    acc = acc.copy()
    acc[..., 2] = np.where(on_floor, _clamp_np(acc[..., 2], hi=0.0), acc[..., 2])
    acc[..., 2] = np.where(on_ceiling, _clamp_np(acc[..., 2], lo=0.0), acc[..., 2])
    with np.errstate(invalid="ignore", over="ignore"):
        at_limit = (vel * vel).sum(-1) >= (lim.max_speed * (1.0 - 16.0 * _F64_EPS)) ** 2
        pushing = (vel * acc).sum(-1) >= -0.5 * _COAST_TOL * (acc * acc).sum(-1)
    return acc * (~(at_limit & pushing))[..., None].astype(acc.dtype)


def _snap_walls_np(pos: np.ndarray, vel: np.ndarray, lim: Limits) -> tuple[np.ndarray, np.ndarray]:
    alt, v_up = -pos[..., 2], -vel[..., 2]
    tol = 16.0 * _F64_EPS * max(1.0, lim.alt_max)
    low = (alt <= lim.alt_min + tol) & (v_up < 0)
    high = (alt >= lim.alt_max - tol) & (v_up > 0)
    stopped = low | high
    if not stopped.any():
        return pos, vel
    pos, vel = pos.copy(), vel.copy()
    pos[..., 2] = np.where(low, -lim.alt_min, np.where(high, -lim.alt_max, pos[..., 2]))
    vel[..., 2] = np.where(stopped, np.zeros_like(v_up), vel[..., 2])
    return pos, vel


def _snap_speed_np(vel: np.ndarray, lim: Limits, force: np.ndarray | None = None) -> np.ndarray:
    speed = _norm_np(vel, keepdim=True)
    near = speed >= lim.max_speed * (1.0 - 16.0 * _F64_EPS)
    if force is not None:
        near = near | force[..., None]
    return np.where(near, vel * _rdiv(lim.max_speed, np.maximum(speed, 1e-12)), vel)


def _event_times_np(pos: np.ndarray, vel: np.ndarray, a: np.ndarray, lim: Limits, min_t: float) -> np.ndarray:
    """(3, M): t_speed, t_ceiling, t_floor (`_event_times`)."""
    h, w, c = -pos[..., 2], -vel[..., 2], -a[..., 2]
    half_c = np.stack([(a * a).sum(-1), 0.5 * c, -0.5 * c])
    lin = np.stack([2.0 * (vel * a).sum(-1), w, -w])
    const = np.stack([(vel * vel).sum(-1) - lim.max_speed**2, h - lim.alt_max, lim.alt_min - h])
    return _first_upcrossing_np(half_c, lin, const, min_t)


def _advance_np(
    pos: np.ndarray, vel: np.ndarray, acc: np.ndarray, t_left: np.ndarray, lim: Limits
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    pos, vel = _snap_walls_np(pos, vel, lim)
    vel = _snap_speed_np(vel, lim)
    a = _effective_accel_np(pos, vel, acc, lim)
    t_speed, t_ceil, t_floor = _event_times_np(pos, vel, a, lim, -_TIME_TOL)
    now_speed = t_speed <= _TIME_TOL
    now_wall = _minimum_np(t_ceil, t_floor) <= _TIME_TOL
    if now_speed.any() or now_wall.any():
        if now_wall.any():
            edge = np.where(t_ceil <= t_floor, np.full_like(t_ceil, -lim.alt_max), np.full_like(t_ceil, -lim.alt_min))
            pos = pos.copy()
            vel = vel.copy()
            pos[..., 2] = np.where(now_wall, edge, pos[..., 2])
            vel[..., 2] = np.where(now_wall, np.zeros_like(edge), vel[..., 2])
        vel = _snap_speed_np(vel, lim, force=now_speed)
        a = _effective_accel_np(pos, vel, acc, lim)
        t_speed, t_ceil, t_floor = _event_times_np(pos, vel, a, lim, _TIME_TOL)
    t_wall = _minimum_np(t_ceil, t_floor)
    t = _minimum_np(t_left, _minimum_np(t_speed, t_wall))
    tt = t[..., None]
    pos = pos + vel * tt + 0.5 * a * tt * tt
    vel = vel + a * tt
    hit_wall = (t_wall <= t) & np.isfinite(t_wall)
    if hit_wall.any():
        bound = np.where(t_ceil <= t_floor, np.full_like(t, lim.alt_max), np.full_like(t, lim.alt_min))
        pos[..., 2] = np.where(hit_wall, -bound, pos[..., 2])
        vel[..., 2] = np.where(hit_wall, np.zeros_like(t), vel[..., 2])
    hit_speed = (t_speed <= t) & np.isfinite(t_speed)
    if hit_speed.any():
        vel = np.where(hit_speed[..., None], clip_norm_np(vel, lim.max_speed), vel)
    return pos, vel, t_left - t


def _free_flight_np(p: np.ndarray, v: np.ndarray, acc: np.ndarray, dt: float, lim: Limits) -> tuple[np.ndarray, np.ndarray]:
    """`_free_flight` (inside, resting)."""
    margin = 1e3 * (16.0 * _F64_EPS * max(1.0, lim.alt_max))  # 1e3 * _wall_tol
    speed = _norm_np(v)
    reach_v = speed + _norm_np(acc) * dt
    alt = -p[..., 2]
    reach_h = np.abs(v[..., 2]) * dt + 0.5 * np.abs(acc[..., 2]) * dt * dt
    inside = (reach_v < lim.max_speed * (1.0 - 1e3 * 16.0 * _F64_EPS)) & (alt - reach_h > lim.alt_min + margin) & (
        alt + reach_h < lim.alt_max - margin
    )
    still = (v == 0).all(-1)
    resting = still & (acc[..., 0] == 0) & (acc[..., 1] == 0) & (acc[..., 2] >= 0) & (alt <= lim.alt_min)
    return inside, resting


def step_point_mass_np(
    pos: np.ndarray, vel: np.ndarray, accel_cmd: np.ndarray, dt: float, lim: Limits
) -> tuple[np.ndarray, np.ndarray]:
    """`step_point_mass` on float64 (M, 3) numpy arrays, bit for bit (see above); new arrays."""
    shape = pos.shape
    if pos.shape[0] <= _FREE_FLIGHT_MAX_BATCH:
        fast = free_flight_step(pos, vel, accel_cmd, dt, lim)
        if fast is not None:
            return fast
    acc = clip_norm_np(np.nan_to_num(accel_cmd), lim.max_accel).reshape(-1, 3)
    p = pos.reshape(-1, 3).copy()
    p[:, 2] = -_clamp_np(-p[:, 2], lim.alt_min, lim.alt_max)
    v = clip_norm_np(vel.reshape(-1, 3), lim.max_speed)
    t_left = np.full(p.shape[:1], float(dt))
    if p.shape[0] <= _FREE_FLIGHT_MAX_BATCH:
        inside, resting = _free_flight_np(p, v, acc, float(dt), lim)
        if (inside | resting).all():
            a = acc * inside[:, None].astype(acc.dtype)
            tt = t_left[:, None]
            p = p + v * tt + 0.5 * a * tt * tt
            v = v + a * tt
            return p.reshape(shape), v.reshape(shape)
    p, v, t_left = _advance_np(p, v, acc, t_left, lim)
    idx = np.flatnonzero(t_left > _TIME_TOL)
    for _ in range(_MAX_EVENTS - 1):
        if idx.size == 0:
            break
        ps, vs, ts = _advance_np(p[idx], v[idx], acc[idx], t_left[idx], lim)
        p[idx], v[idx], t_left[idx] = ps, vs, ts
        idx = idx[ts > _TIME_TOL]
    if idx.size:
        pi, vi = _snap_walls_np(p[idx], v[idx], lim)
        p[idx], v[idx] = pi, vi
        v[idx] = _snap_speed_np(v[idx], lim)
        a = _effective_accel_np(p[idx], v[idx], acc[idx], lim)
        tt = t_left[idx][:, None]
        p[idx] = p[idx] + v[idx] * tt + 0.5 * a * tt * tt
        v[idx] = v[idx] + a * tt
    v = clip_norm_np(v, lim.max_speed)
    p[:, 2] = -_clamp_np(-p[:, 2], lim.alt_min, lim.alt_max)
    p, v = _snap_walls_np(p, v, lim)
    return p.reshape(shape), v.reshape(shape)


def _sqrt_np(x: np.ndarray) -> np.ndarray:
    return torch.sqrt(_t(x)).numpy()


def velocity_tracking_accel_np(
    vel: np.ndarray, vel_target: np.ndarray, max_accel: float | np.ndarray, time_const: float = 1.0
) -> np.ndarray:
    """`velocity_tracking_accel` on float64 arrays, bit for bit."""
    return clip_norm_np((vel_target - vel) / time_const, max_accel)


def goto_accel_np(
    pos: np.ndarray, vel: np.ndarray, target: np.ndarray, max_speed: float | np.ndarray, max_accel: float | np.ndarray,
    time_const: float = 1.0,
) -> np.ndarray:
    """`goto_accel` on float64 arrays, bit for bit: torch's kernels for the norm, the sqrt
    and the minimum. The limits are floats (as `goto_accel` takes them: the plan-aware
    prediction) or per-vehicle (N, 1) arrays (the emulator's guidance); torch divides by a
    float limit and by a tensor one differently, and so does `clip_norm_np`."""
    delta = target - pos
    dist = _norm_np(delta, keepdim=True)
    brake_speed = _sqrt_np(2.0 * 0.5 * max_accel * dist)
    cap = max_speed if isinstance(max_speed, float) else _t(max_speed)
    speed = _minimum_np(brake_speed, torch.clamp(_t(dist / time_const), max=cap).numpy())
    v_des = delta / np.maximum(dist, 1e-9) * speed
    return velocity_tracking_accel_np(vel, v_des, max_accel, time_const)
