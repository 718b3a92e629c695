"""The fused tracker (plmarl_sitl/learning/nn/deploy.py) computes what the reference module computes."""

from __future__ import annotations

import pytest
import torch

from plmarl_sitl.learning.nn import BeliefTracker, make_predictor
from plmarl_sitl.learning.nn.belief import NEVER
from plmarl_sitl.learning.nn.deploy import fuse_tracker, is_fused
from plmarl_sitl.learning.nn.io import TRACKER_ATTRS, freeze


def _tracker(seed: int = 0) -> BeliefTracker:
    torch.manual_seed(seed)
    pred = make_predictor("mlp")
    for p in pred.parameters():  # non-trivial weights (the output layer starts at zero)
        torch.nn.init.normal_(p, std=0.3)
    return BeliefTracker(pred, 10, 1.0).eval()


def _scenario(m: int, gen: torch.Generator) -> list[tuple[float, torch.Tensor, torch.Tensor]]:
    """Seconds 0..11 of held states / reception times with every case the tracker knows:
    updates, predictions, a first reception mid-way, a slot never heard (an agent's own
    slot), and a reception time ahead of t (the twin's catch-up)."""
    out = []
    held = torch.cat([torch.rand(m, 3, generator=gen) * torch.tensor([1000.0, 1000.0, -120.0]), torch.randn(m, 3, generator=gen) * 5], -1)
    t_rx = torch.full((m,), NEVER)
    for t in range(12):
        held = held.clone()
        if t % 5 == 0:  # an update for the first half of the slots
            k = max(1, m // 2)
            held[:k] = held[:k] + torch.randn(k, 6, generator=gen)
            t_rx = t_rx.clone()
            t_rx[:k] = float(t)
        if t == 7 and m > 2:  # first reception of slot m-2, stamped one second ahead of t
            t_rx = t_rx.clone()
            t_rx[m - 2] = 8.0
        out.append((float(t), held, t_rx))
    return out  # slot m-1 is never heard


@pytest.mark.parametrize("m", [1, 3, 19])
def test_fused_tracker_is_bit_identical_on_one_agent(m: int) -> None:
    ref = _tracker()
    fused = freeze(fuse_tracker(ref), TRACKER_ATTRS)
    assert is_fused(fused)
    gen = torch.Generator().manual_seed(m)
    steps = _scenario(m, gen)
    with torch.no_grad():
        b1, s1 = ref.init_state(steps[0][1])
        b2, s2 = fused.init_state(steps[0][1])
        for t, held, t_rx in steps:
            o1 = ref(t, held, t_rx, b1, s1)
            o2 = fused(t, held, t_rx, b2, s2)
            for a, b in zip(o1, o2, strict=True):
                assert torch.equal(a, b)
            _, _, b1, s1 = o1
            _, _, b2, s2 = o2


def test_fused_tracker_other_shapes_use_the_reference() -> None:
    ref = _tracker(1)
    fused = freeze(fuse_tracker(ref), TRACKER_ATTRS)
    gen = torch.Generator().manual_seed(3)
    for shape in [(0,), (2, 4), (2, 3, 3)]:
        held = torch.randn(*shape, 6, generator=gen) * 50
        t_rx = torch.where(torch.rand(shape, generator=gen) > 0.3, torch.zeros(shape), torch.full(shape, NEVER))
        with torch.no_grad():
            b1, s1 = ref.init_state(held)
            b2, s2 = fused.init_state(held)
            for t in range(4):
                o1 = ref(float(t), held, t_rx, b1, s1)
                o2 = fused(float(t), held, t_rx, b2, s2)
                assert all(torch.equal(a, b) for a, b in zip(o1, o2, strict=True))
                _, _, b1, s1 = o1
                _, _, b2, s2 = o2
