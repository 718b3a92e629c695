"""The numpy copy of the point-mass event solver (`step_point_mass_np`, the emulator's fleet)
gives the torch solver's bits, on the states where they could part: at V_max, on and near
the floor and the ceiling, outside the band, commands at, over and without a limit (NaN,
inf), signed zeros, one to forty vehicles (torch's kernels change from 8 rows on)."""

import numpy as np
import pytest
import torch

from plmarl_sitl.model.vehicle import Limits, clip_norm, clip_norm_np, step_point_mass, step_point_mass_np

GROUND = Limits(max_speed=20.0, max_accel=5.0, alt_min=0.0, alt_max=150.0)  # the emulator's
BAND = Limits(max_speed=20.0, max_accel=5.0, alt_min=40.0, alt_max=150.0)  # the twin's


def _edge_batch(rng: np.random.Generator, n: int, lim: Limits) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """n vehicles, each drawn from a mix of the ordinary and the awkward."""
    pos = rng.uniform(-500.0, 500.0, (n, 3))
    alts = np.array([0.0, -0.0, lim.alt_min, lim.alt_max, lim.alt_min + 1e-13, lim.alt_max - 1e-13,
                     lim.alt_max + 3.0, lim.alt_min - 2.0, 0.01, 60.0, 149.99])
    pick = rng.integers(0, 3, n)
    pos[:, 2] = np.where(pick == 0, -rng.choice(alts, n), -rng.uniform(lim.alt_min, lim.alt_max, n))
    direction = rng.normal(size=(n, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    speed = rng.choice([0.0, 1.0, 10.0, lim.max_speed, lim.max_speed * (1 - 1e-15), lim.max_speed * (1 + 1e-15),
                        lim.max_speed * 0.999, 25.0], n)
    vel = direction * speed[:, None]
    vel[rng.random(n) < 0.15] = 0.0
    vel[rng.random(n) < 0.05] = -0.0
    vertical = rng.random(n) < 0.2
    vel[vertical, :2] = 0.0
    vel[vertical, 2] = rng.choice([-3.0, 3.0, -0.0, 0.0, -lim.max_speed, lim.max_speed], int(vertical.sum()))
    adir = rng.normal(size=(n, 3))
    adir /= np.linalg.norm(adir, axis=1, keepdims=True)
    amag = rng.choice([0.0, 0.3, 2.0, lim.max_accel, lim.max_accel * (1 + 1e-15), 7.0, 1e-10], n)
    acc = adir * amag[:, None]
    pushing = rng.random(n) < 0.3  # a command along the velocity (coasting at V_max)
    acc[pushing] = direction[pushing] * amag[pushing, None]
    odd = rng.random(n)
    acc[odd < 0.04] = np.nan
    acc[(odd >= 0.04) & (odd < 0.06)] = np.inf
    acc[(odd >= 0.06) & (odd < 0.08), 2] = -np.inf
    acc[(odd >= 0.08) & (odd < 0.15)] = -0.0
    acc[(odd >= 0.15) & (odd < 0.2), :2] = 0.0
    return pos, vel, acc


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    return a.shape == b.shape and bool((a.view(np.uint64) == b.view(np.uint64)).all())


@pytest.mark.parametrize("lim", [GROUND, BAND], ids=["ground", "band"])
@pytest.mark.parametrize("dt", [0.02, 0.1, 1.0, 7.5])
def test_numpy_solver_is_bit_identical_to_the_torch_solver(lim, dt):
    rng = np.random.default_rng(int(dt * 100) + int(lim.alt_min))
    for n in list(range(1, 41)) * 6:
        pos, vel, acc = _edge_batch(rng, n, lim)
        want_p, want_v = step_point_mass(torch.from_numpy(pos), torch.from_numpy(vel), torch.from_numpy(acc), dt, lim)
        got_p, got_v = step_point_mass_np(pos, vel, acc, dt, lim)
        assert _same(got_p, want_p.numpy()) and _same(got_v, want_v.numpy()), (n, pos, vel, acc)


def test_numpy_solver_follows_a_fleet_for_a_mission():
    """Step after step (each output the next input): a climb off the floor into the band, a
    dash at V_max, hitting the ceiling, a fall to the floor: both solvers stay bit for bit."""
    rng = np.random.default_rng(7)
    n = 20
    pos = np.zeros((n, 3))
    pos[:, :2] = rng.uniform(-50, 50, (n, 2))
    vel = np.zeros((n, 3))
    tp, tv = torch.from_numpy(pos.copy()), torch.from_numpy(vel.copy())
    for k in range(1500):
        phase = k // 250
        acc = rng.normal(size=(n, 3)) * [1.0, 1.0, 0.5, 4.0, 8.0, 0.2][phase]
        acc[:, 2] += [-3.0, 0.0, -6.0, 0.0, 9.0, 5.0][phase]
        if phase == 1:
            acc[: n // 2] = 5.0 * vel[: n // 2] / np.maximum(np.linalg.norm(vel[: n // 2], axis=1, keepdims=True), 1e-9)
        tp, tv = step_point_mass(tp, tv, torch.from_numpy(acc), 0.02, GROUND)
        pos, vel = step_point_mass_np(pos, vel, acc, 0.02, GROUND)
        assert _same(pos, tp.numpy()) and _same(vel, tv.numpy()), k


def test_clip_norm_np_matches_torch_with_per_vehicle_limits():
    rng = np.random.default_rng(3)
    for n in range(1, 30):
        x = rng.normal(size=(n, 3)) * rng.choice([0.0, 1e-13, 1.0, 5.0, 50.0], (n, 1))
        limit = rng.choice([1.0, 5.0, 20.0], (n, 1))
        assert _same(clip_norm_np(x, limit), clip_norm(torch.from_numpy(x), torch.from_numpy(limit)).numpy())
        assert _same(clip_norm_np(x, 5.0), clip_norm(torch.from_numpy(x), 5.0).numpy())
