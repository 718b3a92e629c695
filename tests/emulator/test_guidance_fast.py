"""The guidance (numpy) gives the batched torch controllers' bits: its setpoints-only
shortcut, and every kind of guidance at once."""

from __future__ import annotations

import numpy as np
import torch

from plmarl_sitl.model.vehicle import clip_norm, goto_accel, velocity_tracking_accel
from plmarl_sitl.sitl.autopilot.guidance import Guidance, Kind


def _torch_accel_branch(g: Guidance) -> torch.Tensor:
    """What `Guidance.accel` computes for ACCEL vehicles (and zero for the others)."""
    kind = torch.from_numpy(g.kind)
    out = torch.zeros(len(g.kind), 3, dtype=torch.float64)
    return torch.where((kind == Kind.ACCEL).unsqueeze(-1), clip_norm(torch.from_numpy(g.target), torch.from_numpy(g.max_accel)), out)


def test_setpoints_only_is_the_torch_branch_bit_for_bit() -> None:
    rng = np.random.default_rng(25)
    pos = np.zeros((20, 3))
    for trial in range(200):
        g = Guidance(20)
        g.max_accel[:] = 5.0
        for i in range(20):
            kind = Kind.ACCEL if rng.random() < 0.8 else (Kind.IDLE if rng.random() < 0.5 else Kind.TOUCHDOWN)
            scale = rng.choice([0.0, 1.0, 4.9, 5.0 * (1 - 1e-12), 5.0, 7.0])  # inside, at and over the limit
            vec = rng.normal(size=3)
            vec = vec / np.linalg.norm(vec) * scale if trial % 2 else -np.abs(vec) * 0.0
            g.set(i, kind, tuple(vec))
        got = g.accel(pos, pos, 9.8)
        assert torch.equal(torch.from_numpy(got), _torch_accel_branch(g))


def test_setpoints_only_steps_aside_for_other_kinds() -> None:
    g = Guidance(3)
    g.set(0, Kind.ACCEL, (1.0, 0.0, 0.0))
    g.set(1, Kind.POSITION, (10.0, 0.0, -5.0))
    pos = np.zeros((3, 3))
    a = g.accel(pos, pos, 9.8)
    assert np.abs(a[1]).sum() > 0  # the position controller ran
    assert a[0].tolist() == [1.0, 0.0, 0.0]


def _torch_guidance(g: Guidance, pos: torch.Tensor, vel: torch.Tensor, fall_accel: float) -> torch.Tensor:
    """Every kind through the shared torch controllers (the guidance before its numpy copy)."""
    kind = torch.from_numpy(g.kind).unsqueeze(-1)
    target, ms, ma = torch.from_numpy(g.target), torch.from_numpy(g.max_speed), torch.from_numpy(g.max_accel)
    out = torch.zeros_like(pos)
    accel = clip_norm(target, ma) - torch.from_numpy(g.drag).unsqueeze(-1) * vel if g.drag.any() else clip_norm(target, ma)
    out = torch.where(kind == Kind.ACCEL, accel, out)
    out = torch.where(kind == Kind.VELOCITY, velocity_tracking_accel(vel, clip_norm(target, ms), ma, 0.5), out)
    out = torch.where(kind == Kind.POSITION, goto_accel(pos, vel, target, ms, ma, 0.5), out)
    v_xy = clip_norm((target[:, :2] - pos[:, :2]) / 0.5, ms)
    land = velocity_tracking_accel(vel, torch.cat([v_xy, torch.from_numpy(g.descent).unsqueeze(-1)], dim=-1), ma, 0.5)
    out = torch.where(kind == Kind.LAND, land, out)
    down = torch.zeros_like(pos)
    down[:, 2] = fall_accel
    return torch.where(kind == Kind.FALL, down, out)


def test_every_kind_is_the_torch_controllers_bit_for_bit() -> None:
    """A take-off's climb (at its climb-rate limit), holds at and near their point, landings,
    velocity setpoints, falls, with per-vehicle limits; 1 to 30 vehicles (torch's kernels
    change from 8 rows on)."""
    rng = np.random.default_rng(18)
    kinds = [Kind.IDLE, Kind.ACCEL, Kind.VELOCITY, Kind.POSITION, Kind.LAND, Kind.FALL, Kind.TOUCHDOWN]
    for trial in range(400):
        n = 1 + trial % 30
        g = Guidance(n)
        g.max_speed[:, 0] = rng.choice([1.5, 3.0, 5.0, 12.0], n)
        g.max_accel[:, 0] = rng.choice([2.5, 5.0], n)
        g.descent[:] = rng.choice([0.7, 1.5, 5.0], n)
        if trial % 5 == 0:
            g.drag[:] = 1.0
        pos = rng.normal(size=(n, 3)) * rng.choice([0.0, 1.0, 50.0], (n, 1))
        pos[:, 2] = -np.abs(pos[:, 2])
        vel = rng.normal(size=(n, 3)) * rng.choice([0.0, 0.3, 3.0, 20.0], (n, 1))
        for i in range(n):
            kind = kinds[int(rng.integers(0, len(kinds)))]
            target = pos[i] + rng.normal(size=3) * rng.choice([0.0, 1e-10, 0.1, 5.0, 100.0])
            if kind in (Kind.ACCEL, Kind.VELOCITY):
                target = rng.normal(size=3) * rng.choice([0.0, 1.0, 5.0, 30.0])
            g.set(i, kind, tuple(target))
        got = g.accel(pos, vel, 9.8)
        want = _torch_guidance(g, torch.from_numpy(pos), torch.from_numpy(vel), 9.8)
        assert np.array_equal(got.view(np.uint64), want.numpy().view(np.uint64)), trial


def test_fleet_quiet_substeps_with_drag_are_substep_by_substep_bit_for_bit() -> None:
    """PX4's acceleration setpoints with airframe drag (the command changes with the velocity
    every substep): `step_many` in one call gives `step` after `step`'s bits, and steps aside
    (the same bits still) when a vehicle meets a limit within the run."""
    from plmarl_sitl.model.vehicle import Limits
    from plmarl_sitl.sitl.autopilot.fleet import Fleet

    lim = Limits(max_speed=12.0, max_accel=5.0, alt_min=0.0, alt_max=120.0)
    rng = np.random.default_rng(161)
    fused = 0

    def fleet_at(pos, vel, kinds, targets) -> Fleet:
        f = Fleet(20, lim, {})
        f.guidance.max_speed[:] = 12.0
        f.guidance.max_accel[:] = 5.0
        f.guidance.drag[:] = 1.0
        f.pos_np[:], f.vel_np[:] = pos, vel
        for i in range(20):
            f.guidance.set(i, kinds[i], tuple(targets[i]))
        return f

    for trial in range(300):
        pos = np.column_stack([rng.normal(size=(20, 2)) * 100, -rng.uniform(0.0, 120.0, 20)])
        if trial % 3 == 0:
            pos[:, 2] = -rng.uniform(30.0, 90.0, 20)  # well inside the band: the fused path applies
        vel = rng.normal(size=(20, 3)) * rng.choice([0.5, 3.0, 7.0])
        kinds = [Kind.ACCEL if rng.random() < 0.9 else Kind.IDLE for _ in range(20)]
        targets = rng.normal(size=(20, 3)) * rng.choice([0.5, 2.0, 4.9])
        one, many = fleet_at(pos, vel, kinds, targets), fleet_at(pos, vel, kinds, targets)
        count = int(rng.integers(2, 8))
        fused += many._free_steps(0.02, count) is not None
        many.step_many(0.02, count)
        for _ in range(count):
            one.step(0.02)
        assert np.array_equal(one.pos_np, many.pos_np) and np.array_equal(one.vel_np, many.vel_np), trial
        assert np.array_equal(one.acc_np, many.acc_np) and one.now == many.now, trial
    assert 10 < fused < 290  # both ways were exercised
