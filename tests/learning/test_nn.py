"""Networks, belief tracker and policy input: shapes, masking, Algorithm 1 semantics."""

from __future__ import annotations

import pytest
import torch

from plmarl_sitl.learning.nn import (
    NEVER,
    Actor,
    AttentionFusion,
    Beliefs,
    BeliefTracker,
    DeployedPolicy,
    PolicyInputs,
    build_policy_input,
    make_predictor,
)
from plmarl_sitl.learning.nn.features import EGO_FEATURES, NBR_FEATURES, ring_edges_sq
from plmarl_sitl.model.coverage import SENSING_FEATURES

SCALES = (150.0, 20.0, 5.0, 350.0, 100.0, 60.0)  # alt_max, v_max, a_max, r_comm, claim_m, demand_unit
DEMAND = torch.tensor([[250.0, 250.0, 30.0], [650.0, 400.0, 12.0]])


def _inputs(b: int, m: int, gen: torch.Generator) -> tuple[torch.Tensor, ...]:
    ego = torch.cat([torch.rand(b, 3, generator=gen) * torch.tensor([1000.0, 1000.0, -150.0]), torch.randn(b, 3, generator=gen) * 5], -1)
    bel = torch.cat([torch.rand(b, m, 3, generator=gen) * torch.tensor([1000.0, 1000.0, -150.0]), torch.randn(b, m, 3, generator=gen) * 5], -1)
    sense = torch.rand(b, SENSING_FEATURES, generator=gen)
    return ego, bel, sense


@pytest.mark.parametrize("n_nbrs", [0, 1, 2, 3])
def test_fusion_masks_absent_neighbours(n_nbrs: int) -> None:
    gen = torch.Generator().manual_seed(n_nbrs)
    torch.manual_seed(0)
    m = 4  # slots: N - 1 = 3 possible neighbours plus one failed/never-heard slot
    ego, bel, sense = _inputs(5, m, gen)
    mask = torch.zeros(5, m, dtype=torch.bool)
    mask[:, :n_nbrs] = True
    x = PolicyInputs(ego, bel, mask, sense, torch.zeros(5, dtype=torch.bool), DEMAND.expand(5, 2, 3))
    ego_x, nbr_x, rel_x, mk, _, _ = build_policy_input(x, SCALES[0], SCALES[1], SCALES[3], SCALES[4], SCALES[5], ring_edges_sq())
    assert ego_x.shape == (5, EGO_FEATURES) and nbr_x.shape == (5, m, NBR_FEATURES) and rel_x.shape == (5, m, 3)
    fusion = AttentionFusion()
    h, msg, alpha = fusion(ego_x, nbr_x, rel_x, mk)
    assert h.shape == (5, 32) and msg.shape == (5, 32) and alpha.shape == (5, m)
    assert torch.isfinite(msg).all() and torch.isfinite(alpha).all()
    assert torch.all(alpha[:, n_nbrs:] == 0)
    if n_nbrs:
        assert torch.allclose(alpha.sum(-1), torch.ones(5))
    else:
        assert torch.all(msg == 0)  # ELU(0) with no neighbours
    # Whatever sits in masked slots (a failed neighbour's stale/garbage belief) is ignored.
    bel2 = bel.clone()
    bel2[:, n_nbrs:] = torch.randn_like(bel2[:, n_nbrs:]) * 1e4
    pol = DeployedPolicy(Actor(), *SCALES)
    a1 = pol(ego, bel, mask, sense, torch.zeros(5, dtype=torch.bool), DEMAND.expand(5, 2, 3))
    a2 = pol(ego, bel2, mask, sense, torch.zeros(5, dtype=torch.bool), DEMAND.expand(5, 2, 3))
    assert torch.equal(a1, a2)
    assert a1.shape == (5, 3) and torch.all(a1.abs() <= 5.0)


def test_failed_neighbour_in_twin_batch_shape() -> None:
    """The twin's (B, N) x N layout, a neighbour that failed (dropped from N_i) and the fail flag."""
    gen = torch.Generator().manual_seed(3)
    b, n = 2, 4
    ego, bel, sense = _inputs(b * n, n, gen)
    ego, bel, sense = ego.view(b, n, 6), bel.view(b, n, n, 6), sense.view(b, n, SENSING_FEATURES)
    mask = ~torch.eye(n, dtype=torch.bool).expand(b, n, n).clone()
    mask[0, :, 2] = False  # UAV 2 of env 0 failed: nobody keeps it
    mask[0, 2, :] = False
    fail = torch.zeros(b, n, dtype=torch.bool)
    fail[0] = True
    fail[0, 2] = False
    torch.manual_seed(1)
    pol = DeployedPolicy(Actor(), *SCALES)
    out = pol(ego, bel, mask, sense, fail)
    assert out.shape == (b, n, 3) and torch.isfinite(out).all()
    # The fail flag is an input: flipping it changes the action of an agent.
    fail2 = fail.clone()
    fail2[1, 0] = True
    assert not torch.equal(pol(ego, bel, mask, sense, fail2)[1, 0], out[1, 0])


def _cv_tracker() -> BeliefTracker:
    return BeliefTracker(make_predictor("cv"), 10, 1.0)


def test_tracker_follows_algorithm_1() -> None:
    tr = _cv_tracker()
    held = torch.tensor([[100.0, 200.0, -80.0, 2.0, -1.0, 0.0], [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]])
    t_rx = torch.tensor([0.0, NEVER])
    buf, seen = tr.init_state(held)
    b, aoi, buf, seen = tr(0.0, held, t_rx, buf, seen)
    assert torch.equal(b[0], held[0]) and aoi[0] == 1.0  # reception: true state, P-AoI reset
    # First reception back-fills the buffer with the constant-velocity past.
    assert torch.allclose(buf[0, 0, :3], held[0, :3] - 9 * held[0, 3:])
    for t in range(1, 5):
        b, aoi, buf, seen = tr(float(t), held, t_rx, buf, seen)
        assert aoi[0] == t  # P-AoI grows (Eq. 1)
        assert torch.allclose(b[0, :3], held[0, :3] + t * held[0, 3:])  # phi = CV here
        assert torch.equal(buf[0, -1], b[0])  # appended to the buffer
    # A new update at t = 5 replaces the prediction with the received state.
    new = held.clone()
    new[0, :3] += 7.0
    b, aoi, buf, seen = tr(5.0, new, torch.tensor([5.0, NEVER]), buf, seen)
    assert torch.equal(b[0], new[0]) and aoi[0] == 1.0
    # The buffer keeps its history (Algorithm 1 appends, it does not reset).
    assert torch.allclose(buf[0, -2, :3], held[0, :3] + 4 * held[0, 3:])


@pytest.mark.parametrize("kind", ["mlp", "gru", "cv", "hold"])
def test_tracker_batch_shapes_agree(kind: str) -> None:
    """One deployed agent (M,) and the twin (B, N, N) give the same beliefs for the same data."""
    torch.manual_seed(0)
    tr = BeliefTracker(make_predictor(kind), 10, 1.0)
    gen = torch.Generator().manual_seed(5)
    held = torch.randn(2, 3, 3, 6, generator=gen) * 10
    t_rx = torch.zeros(2, 3, 3)
    t_rx[0, 1, 2] = NEVER
    wrap_all, wrap_one = Beliefs(tr), Beliefs(tr)
    for t in range(0, 12):
        if t == 6:
            held = held + 1.0
            t_rx = torch.where(t_rx > NEVER / 2, torch.full_like(t_rx, 6.0), t_rx)
        ball, _ = wrap_all.advance(t, held, t_rx)
        bone, _ = wrap_one.advance(t, held[1, 2], t_rx[1, 2])
        assert torch.allclose(ball[1, 2], bone, atol=1e-5)
        assert torch.isfinite(ball).all()


def test_catch_up_equals_per_second_advance() -> None:
    torch.manual_seed(0)
    tr = BeliefTracker(make_predictor("mlp"), 10, 1.0)
    held0 = torch.randn(4, 6)
    held1 = held0 + 3.0
    per_second, replay = Beliefs(tr), Beliefs(tr)
    for t in range(0, 7):
        h, r = (held1, torch.full((4,), 5.0)) if t >= 5 else (held0, torch.zeros(4))
        want, _ = per_second.advance(t, h, r)
    replay.catch_up(3, held0, torch.zeros(4))
    got, _ = replay.catch_up(6, held1, torch.full((4,), 5.0))
    assert torch.allclose(got, want)
