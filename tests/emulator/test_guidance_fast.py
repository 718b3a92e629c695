"""The guidance's setpoints-only shortcut gives the batched torch controllers' bits."""

from __future__ import annotations

import numpy as np
import torch

from plmarl_sitl.model.vehicle import clip_norm
from plmarl_sitl.sitl.autopilot.guidance import Guidance, Kind


def _torch_accel_branch(g: Guidance) -> torch.Tensor:
    """What `Guidance.accel` computes for ACCEL vehicles (and zero for the others)."""
    kind = torch.from_numpy(g.kind)
    out = torch.zeros(len(g.kind), 3, dtype=torch.float64)
    return torch.where((kind == Kind.ACCEL).unsqueeze(-1), clip_norm(torch.from_numpy(g.target), torch.from_numpy(g.max_accel)), out)


def test_setpoints_only_is_the_torch_branch_bit_for_bit() -> None:
    rng = np.random.default_rng(25)
    pos = torch.zeros(20, 3, dtype=torch.float64)
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
        assert torch.equal(got, _torch_accel_branch(g))


def test_setpoints_only_steps_aside_for_other_kinds() -> None:
    g = Guidance(3)
    g.set(0, Kind.ACCEL, (1.0, 0.0, 0.0))
    g.set(1, Kind.POSITION, (10.0, 0.0, -5.0))
    pos = torch.zeros(3, 3, dtype=torch.float64)
    a = g.accel(pos, pos, 9.8)
    assert a[1].abs().sum() > 0  # the position controller ran
    assert torch.equal(a[0], torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64))


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
