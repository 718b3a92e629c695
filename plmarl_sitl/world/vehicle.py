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

from dataclasses import dataclass

import torch

from plmarl_sitl.config import VehicleModel

_TIME_TOL = 1e-7  # s: roots closer to "now" than this are the event we are sitting on
_MAX_EVENTS = 5  # speed, wall, speed again after the wall, plus numerical slack


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


def _first_positive_root(half_c: torch.Tensor, b: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
    """Smallest t > tol with half_c t^2 + b t + d = 0, else +inf (elementwise)."""
    inf = torch.full_like(b, float("inf"))
    # Linear case.
    lin = torch.where(b.abs() > 1e-12, -d / torch.where(b.abs() > 1e-12, b, torch.ones_like(b)), inf)
    lin = torch.where(lin > _TIME_TOL, lin, inf)
    # Quadratic case.
    disc = b * b - 4.0 * half_c * d
    sq = torch.sqrt(torch.clamp(disc, min=0.0))
    safe_c = torch.where(half_c.abs() > 1e-12, half_c, torch.ones_like(half_c))
    r1 = (-b - sq) / (2.0 * safe_c)
    r2 = (-b + sq) / (2.0 * safe_c)
    r1 = torch.where(r1 > _TIME_TOL, r1, inf)
    r2 = torch.where(r2 > _TIME_TOL, r2, inf)
    quad = torch.where(disc >= 0, torch.minimum(r1, r2), inf)
    return torch.where(half_c.abs() > 1e-12, quad, lin)


def _effective_accel(
    pos: torch.Tensor, vel: torch.Tensor, acc: torch.Tensor, lim: Limits
) -> torch.Tensor:
    alt = -pos[..., 2]
    v_up = -vel[..., 2]
    a_up = -acc[..., 2]
    tol = 1e-4 * max(1.0, lim.alt_max)
    on_floor = (alt <= lim.alt_min + tol) & (v_up <= 1e-6)
    on_ceiling = (alt >= lim.alt_max - tol) & (v_up >= -1e-6)
    a_up = torch.where(on_floor, torch.clamp(a_up, min=0.0), a_up)
    a_up = torch.where(on_ceiling, torch.clamp(a_up, max=0.0), a_up)
    acc = torch.cat([acc[..., :2], (-a_up).unsqueeze(-1)], dim=-1)
    speed = torch.linalg.vector_norm(vel, dim=-1)
    at_limit = speed >= lim.max_speed * (1.0 - 1e-6)
    pushing = (vel * acc).sum(-1) >= 0.0
    coast = (at_limit & pushing).unsqueeze(-1)
    return torch.where(coast, torch.zeros_like(acc), acc)


def _advance(
    pos: torch.Tensor, vel: torch.Tensor, acc: torch.Tensor, t_left: torch.Tensor, lim: Limits
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Move (M, 3) states ballistically up to the first event or the end of the step."""
    a = _effective_accel(pos, vel, acc, lim)
    # Event 1: |v + a t| = V  ->  |a|^2 t^2 + 2 (v.a) t + |v|^2 - V^2 = 0
    va = (vel * a).sum(-1)
    aa = (a * a).sum(-1)
    vv = (vel * vel).sum(-1)
    t_speed = _first_positive_root(aa, 2.0 * va, vv - lim.max_speed**2)
    t_speed = torch.where(aa > 1e-12, t_speed, torch.full_like(t_speed, float("inf")))
    # Event 2: altitude reaches a band edge (altitude positive up).
    h, w, c = -pos[..., 2], -vel[..., 2], -a[..., 2]
    t_ceil = _first_positive_root(0.5 * c, w, h - lim.alt_max)
    t_floor = _first_positive_root(0.5 * c, w, h - lim.alt_min)
    t_wall = torch.minimum(t_ceil, t_floor)
    t = torch.minimum(t_left, torch.minimum(t_speed, t_wall))
    tt = t.unsqueeze(-1)
    pos = pos + vel * tt + 0.5 * a * tt * tt
    vel = vel + a * tt
    hit_wall = (t_wall <= t) & torch.isfinite(t_wall)
    if bool(hit_wall.any()):
        bound = torch.where(t_ceil <= t_floor, torch.full_like(h, lim.alt_max), torch.full_like(h, lim.alt_min))
        pos[..., 2] = torch.where(hit_wall, -bound, pos[..., 2])
        vel[..., 2] = torch.where(hit_wall, torch.zeros_like(h), vel[..., 2])
    hit_speed = (t_speed <= t) & torch.isfinite(t_speed)
    if bool(hit_speed.any()):
        vel = torch.where(hit_speed.unsqueeze(-1), clip_norm(vel, lim.max_speed), vel)
    return pos, vel, t_left - t


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
    acc = clip_norm(torch.nan_to_num(accel_cmd), lim.max_accel).reshape(-1, 3)
    # Start inside the limits: a state handed in slightly outside (e.g. float32 round-off
    # or a fresh spawn) is projected back so the event solver's preconditions hold.
    p = pos.reshape(-1, 3).clone()
    p[:, 2] = -torch.clamp(-p[:, 2], lim.alt_min, lim.alt_max)
    v = clip_norm(vel.reshape(-1, 3), lim.max_speed)
    t_left = torch.full(p.shape[:1], float(dt), dtype=p.dtype, device=p.device)
    p, v, t_left = _advance(p, v, acc, t_left, lim)
    # Only vehicles that met an event this step have time left: iterate on that subset.
    idx = torch.nonzero(t_left > 0).flatten()
    for _ in range(_MAX_EVENTS - 1):
        if idx.numel() == 0:
            break
        ps, vs, ts = _advance(p[idx], v[idx], acc[idx], t_left[idx], lim)
        p[idx], v[idx] = ps, vs
        idx = idx[ts > 0]
    # Round-off guard: the analytic solution already respects the limits.
    v = clip_norm(v, lim.max_speed)
    p[:, 2] = -torch.clamp(-p[:, 2], lim.alt_min, lim.alt_max)
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
