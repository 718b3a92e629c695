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
