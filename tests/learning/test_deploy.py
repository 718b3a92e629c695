"""The fused deployment forms (plmarl_sitl/learning/nn/deploy.py) compute what the reference modules compute."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from torch.nn import functional as F

from plmarl_sitl.learning.nn import Actor, BeliefTracker, DeployedPolicy, make_predictor
from plmarl_sitl.learning.nn.belief import NEVER
from plmarl_sitl.learning.nn.deploy import (
    FusedKinematicTracker,
    FusedPolicy,
    fuse_policy,
    fuse_tracker,
    fused_from_files,
    is_fused,
)
from plmarl_sitl.learning.nn.io import POLICY_ATTRS, TRACKER_ATTRS, freeze, quiet_torchscript
from plmarl_sitl.learning.nn.predictor import KinematicPredictor
from plmarl_sitl.model.coverage import SENSING_FEATURES

SCALES = (1000.0, 1000.0, 150.0, 20.0, 5.0, 350.0)


def _tracker(seed: int = 0) -> BeliefTracker:
    torch.manual_seed(seed)
    pred = make_predictor("mlp")
    for p in pred.parameters():  # non-trivial weights (the output layer starts at zero)
        torch.nn.init.normal_(p, std=0.3)
    return BeliefTracker(pred, 10, 1.0).eval()


def _policy(seed: int = 0) -> DeployedPolicy:
    torch.manual_seed(seed)
    return DeployedPolicy(Actor(), *SCALES).eval()


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


@pytest.mark.parametrize("m", [0, 1, 5, 19])
def test_fused_policy_equals_reference(m: int) -> None:
    ref = _policy(m)
    fused = freeze(fuse_policy(ref), POLICY_ATTRS)
    assert is_fused(fused)
    gen = torch.Generator().manual_seed(10 + m)
    ego = torch.tensor([300.0, 650.0, -90.0, 3.0, -2.0, 0.5])
    beliefs = torch.cat([torch.rand(m, 3, generator=gen) * torch.tensor([1000.0, 1000.0, -120.0]), torch.randn(m, 3, generator=gen) * 5], -1)
    sense = torch.rand(SENSING_FEATURES, generator=gen)
    masks = [torch.ones(m, dtype=torch.bool), torch.zeros(m, dtype=torch.bool), torch.rand(m, generator=gen) > 0.5]
    with torch.no_grad():
        for mask in masks:
            for fail in (False, True):
                want = ref(ego, beliefs, mask, sense, torch.tensor(fail))
                got = fused(ego, beliefs, mask, sense, torch.tensor(fail))
                assert got.shape == (3,)
                assert torch.allclose(got, want, rtol=1e-5, atol=1e-5), (got, want)
        # batched (the twin's shapes) run the reference itself
        b = (2, 3)
        args = (ego.expand(b + (6,)), beliefs.expand(b + (m, 6)), masks[2].expand(b + (m,)), sense.expand(b + (SENSING_FEATURES,)), torch.ones(b, dtype=torch.bool))
        assert torch.equal(fused(*args), ref(*args))


class _TanhKinematicPredictor(KinematicPredictor):
    """phi as files before the fused form evaluated it (tanh layers)."""

    def forward(self, buf: torch.Tensor, aoi: torch.Tensor) -> torch.Tensor:
        x = torch.cat([buf.flatten(-2), aoi.unsqueeze(-1)], -1)
        h = torch.tanh(F.linear(x, self.l1.weight @ self.T.t(), self.l1.bias))
        u = torch.tanh(self.l3(torch.tanh(self.l2(h))))
        return torch.cat([buf.select(-2, -1), u], -1) @ self.KG


def test_fused_from_unfused_files(tmp_path: Path) -> None:
    """Shipped files made before the fused form are re-exported from their frozen graphs."""
    torch.manual_seed(4)
    pred = _TanhKinematicPredictor()
    for p in pred.parameters():
        torch.nn.init.normal_(p, std=0.1)
    with quiet_torchscript():
        torch.jit.save(freeze(BeliefTracker(pred, 10, 1.0), TRACKER_ATTRS), str(tmp_path / "predictor.pt"))
        torch.jit.save(freeze(_policy(4), POLICY_ATTRS), str(tmp_path / "policy.pt"))
        old_t, old_p = torch.jit.load(str(tmp_path / "predictor.pt")), torch.jit.load(str(tmp_path / "policy.pt"))
    tracker, policy = fused_from_files(old_t, old_p)
    assert isinstance(tracker, FusedKinematicTracker) and isinstance(policy, FusedPolicy)
    tracker, policy = freeze(tracker, TRACKER_ATTRS), freeze(policy, POLICY_ATTRS)
    gen = torch.Generator().manual_seed(5)
    steps = _scenario(7, gen)
    ego = torch.tensor([500.0, 500.0, -100.0, 1.0, 0.0, 0.0])
    mask = torch.tensor([True] * 5 + [False] * 2)
    sense = torch.rand(SENSING_FEATURES, generator=gen)
    with torch.no_grad():
        b1, s1 = old_t.init_state(steps[0][1])
        b2, s2 = tracker.init_state(steps[0][1])
        for t, held, t_rx in steps:
            e1, a1, b1, s1 = old_t(t, held, t_rx, b1, s1)
            e2, a2, b2, s2 = tracker(t, held, t_rx, b2, s2)
            assert torch.allclose(e1, e2, rtol=1e-5, atol=1e-4) and torch.equal(a1, a2) and torch.equal(s1, s2)
            want = old_p(ego, e1, mask, sense, torch.tensor(True))
            assert torch.allclose(policy(ego, e1, mask, sense, torch.tensor(True)), want, rtol=1e-5, atol=1e-5)
