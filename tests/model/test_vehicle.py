"""Point-mass dynamics: limits are never exceeded and integration is exact."""

import math

import numpy as np
import torch
from hypothesis import example, given, settings
from hypothesis import strategies as st

from plmarl_sitl.model.vehicle import Limits, goto_accel, step_point_mass

LIM = Limits(max_speed=20.0, max_accel=5.0, alt_min=40.0, alt_max=150.0)
f64 = torch.float64

coord = st.floats(-30.0, 30.0)
vec = st.tuples(coord, coord, coord)


def _state(alt, v, a):
    pos = torch.tensor([[10.0, -5.0, -alt]], dtype=f64)
    vel = torch.tensor([v], dtype=f64)
    acc = torch.tensor([a], dtype=f64)
    return pos, vel, acc


@settings(max_examples=300, deadline=None)
@given(alt=st.floats(40.0, 150.0), v=vec, a=vec, dt=st.floats(0.01, 20.0))
def test_limits_never_exceeded(alt, v, a, dt):
    pos, vel, acc = _state(alt, v, a)
    p, u = step_point_mass(pos, vel, acc, dt, LIM)
    assert float(torch.linalg.vector_norm(u)) <= LIM.max_speed * (1 + 1e-9)
    assert LIM.alt_min - 1e-9 <= float(-p[0, 2]) <= LIM.alt_max + 1e-9


@settings(max_examples=200, deadline=None)
@given(alt=st.floats(40.0, 150.0), v=vec, a=vec, dt=st.floats(0.1, 10.0), k=st.integers(2, 13))
# Found by hypothesis: at V_max with a nearly perpendicular command; on the floor still
# moving down; on the floor with a denormal upward speed; a dip below V_max ending
# inside a substep.
@example(alt=40.0, v=(20.0, -1.175494351e-38, 0.0), a=(0.0, 1.0, 0.0), dt=1.0, k=2)
@example(alt=40.0, v=(0.5, 0.0, 20.0), a=(1.0, 0.0, 19.0), dt=1.0, k=2)
@example(alt=40.0, v=(0.0, 0.0, -3.8692477758379256e-280), a=(0.0, 0.0, 1.0), dt=1.0, k=2)
@example(alt=40.0, v=(30.0, -30.0, -30.0), a=(-10.143614542508722, -30.0, 20.0), dt=0.1, k=6)
@example(alt=40.0, v=(20.0, 0.0, 0.001953125), a=(1.0, 0.0, 0.0), dt=1.0, k=2)
@example(alt=150.0, v=(2.4638862154841235, -13.368143574250201, 20.0), a=(20.48632938067732, -10.707911964319262, -9.744309589036298), dt=0.1, k=6)
def test_substeps_equal_one_step(alt, v, a, dt, k):
    """Exact integration: k steps of dt/k land where one step of dt does, limits included."""
    pos, vel, acc = _state(alt, v, a)
    p1, v1 = step_point_mass(pos, vel, acc, dt, LIM)
    p2, v2 = pos, vel
    for _ in range(k):
        p2, v2 = step_point_mass(p2, v2, acc, dt / k, LIM)
    assert torch.allclose(p1, p2, atol=1e-6), (p1, p2)
    assert torch.allclose(v1, v2, atol=1e-6), (v1, v2)


def test_matches_closed_form_without_limits():
    pos = torch.tensor([[0.0, 0.0, -100.0]], dtype=f64)
    vel = torch.tensor([[1.0, -2.0, 0.5]], dtype=f64)
    acc = torch.tensor([[0.6, 0.8, 0.0]], dtype=f64)
    p, v = step_point_mass(pos, vel, acc, 3.0, LIM)
    assert torch.allclose(p, pos + vel * 3.0 + 0.5 * acc * 9.0)
    assert torch.allclose(v, vel + acc * 3.0)


def test_accel_command_clipped():
    pos, vel, acc = _state(100.0, (0.0, 0.0, 0.0), (30.0, 40.0, 0.0))
    _, v = step_point_mass(pos, vel, acc, 1.0, LIM)
    assert math.isclose(float(torch.linalg.vector_norm(v)), 5.0, rel_tol=1e-12)


def test_speed_saturates_then_coasts():
    pos, vel, acc = _state(100.0, (0.0, 0.0, 0.0), (5.0, 0.0, 0.0))
    p, v = step_point_mass(pos, vel, acc, 10.0, LIM)
    # 4 s to reach 20 m/s (40 m), then 6 s at 20 m/s (120 m).
    assert math.isclose(float(v[0, 0]), 20.0, rel_tol=1e-12)
    assert math.isclose(float(p[0, 0]) - 10.0, 160.0, rel_tol=1e-9)


def test_floor_stops_descent():
    pos, vel, acc = _state(45.0, (0.0, 0.0, 2.0), (0.0, 0.0, 3.0))  # NED: +z is down
    p, v = step_point_mass(pos, vel, acc, 10.0, LIM)
    assert float(-p[0, 2]) == 40.0 and float(v[0, 2]) == 0.0


def test_nan_command_is_ignored():
    pos, vel, acc = _state(100.0, (1.0, 0.0, 0.0), (float("nan"), 0.0, float("inf")))
    p, v = step_point_mass(pos, vel, acc, 1.0, LIM)
    assert torch.isfinite(p).all() and torch.isfinite(v).all()


def test_float32_batch_agrees_with_float64():
    g = torch.Generator().manual_seed(3)
    pos = torch.cat([torch.rand(256, 2, generator=g, dtype=f64) * 1000, -(40 + 110 * torch.rand(256, 1, generator=g, dtype=f64))], -1)
    vel = (torch.rand(256, 3, generator=g, dtype=f64) * 2 - 1) * 11
    acc = (torch.rand(256, 3, generator=g, dtype=f64) * 2 - 1) * 5
    p64, v64 = step_point_mass(pos, vel, acc, 3.0, LIM)
    p32, v32 = step_point_mass(pos.float(), vel.float(), acc.float(), 3.0, LIM)
    assert torch.allclose(p32.double(), p64, atol=1e-2)
    assert torch.allclose(v32.double(), v64, atol=1e-3)


def test_goto_reaches_target_and_stops():
    pos = torch.tensor([[0.0, 0.0, -100.0]], dtype=f64)
    vel = torch.zeros(1, 3, dtype=f64)
    target = torch.tensor([[300.0, -200.0, -80.0]], dtype=f64)
    for _ in range(200):
        pos, vel = step_point_mass(pos, vel, goto_accel(pos, vel, target, 20.0, 5.0), 0.5, LIM)
    assert float(torch.linalg.vector_norm(pos - target)) < 1.0
    assert float(torch.linalg.vector_norm(vel)) < 0.5


@settings(max_examples=300, deadline=None)
@given(
    alt=st.one_of(st.just(40.0), st.floats(40.0, 150.0)),
    v=st.one_of(st.just((0.0, 0.0, 0.0)), vec),
    a=vec,
    dt=st.sampled_from([0.02, 0.1, 1.0, 3.0]),
    dtype=st.sampled_from([torch.float32, f64]),
)
# Found by CI: the solver's textbook root formula cancelled in float32 and put this
# vehicle, 1 m above the floor, onto it; the shortcut had it right.
@example(alt=41.0, v=(0.0, 0.0, 1.0), a=(0.0, 0.0, 1e-9), dt=0.02, dtype=torch.float32)
# Found by CI: on the floor with a subnormal sink rate the shortcut took the vehicle for
# one standing still (the rate squares to 0 in the norm) and kept what the solver zeroes.
@example(alt=40.0, v=(0.0, 0.0, 1.401298464324817e-45), a=(0.0, 0.0, 0.0), dt=0.02, dtype=torch.float32)
def test_free_flight_shortcut_is_bit_identical_to_the_event_solver(alt, v, a, dt, dtype):
    """Small batches take a ballistic shortcut when no vehicle can meet a limit; it must
    give exactly what the event solver gives (three vehicles: mixed and all-free cases)."""
    import plmarl_sitl.model.vehicle as vehicle

    pos = torch.tensor([[0.0, 0.0, -alt], [5.0, 1.0, -90.0], [0.0, 0.0, -40.0]], dtype=dtype)
    vel = torch.tensor([v, [1.0, 2.0, 0.5], [0.0, 0.0, 0.0]], dtype=dtype)
    acc = torch.tensor([a, [0.5, -0.5, 0.1], [0.0, 0.0, 0.0]], dtype=dtype)
    shortcut = step_point_mass(pos, vel, acc, dt, LIM)
    saved = vehicle._FREE_FLIGHT_MAX_BATCH
    vehicle._FREE_FLIGHT_MAX_BATCH = 0
    try:
        solver = step_point_mass(pos, vel, acc, dt, LIM)
    finally:
        vehicle._FREE_FLIGHT_MAX_BATCH = saved
    assert torch.equal(shortcut[0], solver[0]) and torch.equal(shortcut[1], solver[1])


@settings(max_examples=300, deadline=None)
@given(
    alt=st.one_of(st.just(0.0), st.just(LIM.alt_max), st.floats(0.0, LIM.alt_max)),
    v=st.one_of(st.just((0.0, 0.0, 0.0)), vec),
    a=st.one_of(st.just((0.0, 0.0, 0.0)), vec),
    speed_frac=st.sampled_from([0.0, 0.5, 0.999, 1.0 - 1e-12, 1.0]),
    dt=st.sampled_from([0.02, 0.1, 1.0]),
)
def test_numpy_free_flight_is_bit_identical_to_the_torch_path(alt, v, a, speed_frac, dt):
    """The emulator's fleet steps through the numpy copy of the free-flight shortcut; with
    autograd on the same call takes the torch path: both must give the same bits, on the
    ground, at the ceiling, at and near V_max (where the numpy path must step aside)."""
    n = 20
    gen = torch.Generator().manual_seed(int(alt * 1000 + dt * 10) % 2**31)
    pos = torch.rand(n, 3, generator=gen, dtype=f64) * 100.0
    pos[:, 2] = -torch.rand(n, generator=gen, dtype=f64) * LIM.alt_max
    pos[0, 2] = -alt
    vel = (torch.rand(n, 3, generator=gen, dtype=f64) - 0.5) * 4.0
    vel[0] = torch.tensor(v, dtype=f64)
    direction = torch.tensor([0.6, 0.8, 0.0], dtype=f64)
    vel[1] = direction * LIM.max_speed * speed_frac
    acc = (torch.rand(n, 3, generator=gen, dtype=f64) - 0.5) * 2.0
    acc[0] = torch.tensor(a, dtype=f64)
    acc[2] = direction * LIM.max_accel * speed_frac
    fast = step_point_mass(pos, vel, acc, dt, LIM)
    slow = step_point_mass(pos.clone().requires_grad_(), vel, acc, dt, LIM)
    assert torch.equal(fast[0], slow[0].detach()) and torch.equal(fast[1], slow[1].detach())


def test_numpy_free_flight_serves_a_cruising_fleet():
    """The case it is for: 20 vehicles cruising mid-band take the numpy path."""
    import plmarl_sitl.model.vehicle as vehicle

    pos = torch.zeros(20, 3, dtype=f64)
    pos[:, 2] = -60.0
    vel = torch.full((20, 3), 1.0, dtype=f64)
    vel[:, 2] = 0.0
    acc = torch.full((20, 3), 0.5, dtype=f64)
    assert vehicle._free_flight_numpy(pos, vel, acc, 0.02, LIM) is not None


@settings(max_examples=150, deadline=None)
@given(
    alt=st.floats(40.0, 150.0), v=vec, a=vec, speed_frac=st.floats(0.0, 1.0),
    dt=st.sampled_from([0.02, 0.1]), count=st.integers(1, 7), seed=st.integers(0, 2**31 - 1),
)
def test_multi_step_free_flight_is_bit_identical_to_step_after_step(alt, v, a, speed_frac, dt, count, seed):
    """The emulator's quiet substeps in one call give the bits of `count` calls of the
    single step, or step aside (None) exactly when one of those steps would not apply;
    near the floor, the ceiling, V_max and at rest."""
    from plmarl_sitl.model.vehicle import free_flight_step, free_flight_steps

    n = 20
    gen = torch.Generator().manual_seed(seed)
    pos = torch.rand(n, 3, generator=gen, dtype=f64) * 100.0
    pos[:, 2] = -(LIM.alt_min + torch.rand(n, generator=gen, dtype=f64) * (LIM.alt_max - LIM.alt_min))
    pos[0, 2] = -alt
    pos[3, 2] = -LIM.alt_min  # resting on the floor ...
    vel = (torch.rand(n, 3, generator=gen, dtype=f64) - 0.5) * 4.0
    vel[0] = torch.tensor(v, dtype=f64).clamp(-LIM.max_speed / 2, LIM.max_speed / 2)
    direction = torch.tensor([0.6, 0.8, 0.0], dtype=f64)
    vel[1] = direction * LIM.max_speed * speed_frac
    vel[3] = 0.0
    acc = (torch.rand(n, 3, generator=gen, dtype=f64) - 0.5) * 2.0
    acc[0] = torch.tensor(a, dtype=f64).clamp(-LIM.max_accel / 2, LIM.max_accel / 2)
    acc[1] = direction * LIM.max_accel * speed_frac
    acc[3] = torch.tensor([0.0, 0.0, 1.0], dtype=f64)  # ... pushed into it
    p, u, c = pos.numpy(), vel.numpy(), acc.numpy()
    one = (p, u)
    for _ in range(count):
        one = free_flight_step(one[0], one[1], c, dt, LIM) if one is not None else None
    many = free_flight_steps(p, u, c, dt, count, LIM)
    if one is None:
        assert many is None
    else:
        assert many is not None
        assert np.array_equal(many[0], one[0]) and np.array_equal(many[1], one[1])
        assert all(np.signbit(many[k]).tolist() == np.signbit(one[k]).tolist() for k in (0, 1))
