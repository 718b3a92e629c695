"""lambda_2 on known graphs, the comm graph, and P-AoI / held neighbour states."""

import math

import pytest
import torch

from plmarl_sitl.mission import Channel
from plmarl_sitl.model.graph import algebraic_connectivity, link_mask, weighted_adjacency
from plmarl_sitl.model.signalling import Holdings, paoi, signalling_update


def _complete(n):
    return torch.ones(n, n, dtype=torch.float64) - torch.eye(n, dtype=torch.float64)


def _path(n):
    a = torch.zeros(n, n, dtype=torch.float64)
    for i in range(n - 1):
        a[i, i + 1] = a[i + 1, i] = 1.0
    return a


@pytest.mark.parametrize("n", [2, 3, 4, 7])
def test_lambda2_complete_graph_is_n(n):
    assert math.isclose(float(algebraic_connectivity(_complete(n))), n, rel_tol=1e-9)


@pytest.mark.parametrize("n", [2, 4, 5, 10])
def test_lambda2_path_graph(n):
    assert math.isclose(float(algebraic_connectivity(_path(n))), 2 * (1 - math.cos(math.pi / n)), rel_tol=1e-9)


def test_lambda2_disconnected_is_zero():
    a = torch.zeros(4, 4, dtype=torch.float64)
    a[0, 1] = a[1, 0] = a[2, 3] = a[3, 2] = 1.0
    assert abs(float(algebraic_connectivity(a))) < 1e-9


def test_lambda2_ignores_dead_nodes():
    alive = torch.tensor([True, True, True, False])
    assert math.isclose(float(algebraic_connectivity(_complete(4), alive)), 3.0, rel_tol=1e-9)
    assert float(algebraic_connectivity(_complete(4), torch.tensor([True, False, False, False]))) == 0.0


def test_lambda2_batched_and_weighted():
    batch = torch.stack([_complete(4) * 2.0, _path(4)])
    lam = algebraic_connectivity(batch)
    assert torch.allclose(lam, torch.tensor([8.0, 2 * (1 - math.cos(math.pi / 4))], dtype=torch.float64))


def test_links_need_range_and_sinr():
    ch = Channel()
    pos = torch.tensor([[0.0, 0.0, -100.0], [300.0, 0.0, -100.0], [700.0, 0.0, -100.0]])
    rx, sinr = link_mask(pos, torch.tensor([True, True, True]), ch, comm_m=350.0)
    assert rx[0, 1] and rx[1, 0] and not rx[0, 2] and not rx[2, 0]
    # A loud interferer right next to the receiver breaks an in-range link.
    noisy = Channel(interference_activity=1.0)
    pos2 = torch.tensor([[0.0, 0.0, -100.0], [300.0, 0.0, -100.0], [20.0, 0.0, -100.0]])
    rx2, _ = link_mask(pos2, torch.tensor([True, True, True]), noisy, comm_m=350.0)
    assert not rx2[0, 1]
    w = weighted_adjacency(rx, sinr)
    assert w[0, 1] > 1.0 and w[0, 2] == 0 and torch.allclose(w, w.T)


def test_paoi_equation_1():
    t = torch.arange(0, 31)
    assert paoi(t, 15).tolist() == [1] + list(range(1, 15)) + [1] + list(range(1, 15)) + [1]


def test_holdings_sawtooth_and_drop():
    n = 3
    h = Holdings.empty((), n, torch.float64)
    state = torch.arange(18, dtype=torch.float64).view(3, 6)
    everyone = torch.ones(n, n, dtype=torch.bool)
    h = signalling_update(h, 0.0, everyone, state, drop_after_missed=2)
    assert h.neighbour_mask(2).tolist() == [[False, True, True], [True, False, True], [True, True, False]]
    assert torch.equal(h.state[0, 2], state[2])
    assert [float(h.aoi(t)[0, 1]) for t in (0, 1, 7, 14)] == [1.0, 1.0, 7.0, 14.0]
    # Node 2 goes silent: missed once, still a neighbour; twice, dropped, and f is set.
    silent = everyone.clone()
    silent[:, 2] = False
    h = signalling_update(h, 15.0, silent, state + 1, drop_after_missed=2)
    assert h.neighbour_mask(2)[0, 2] and not h.lost.any()
    assert float(h.aoi(16.0)[0, 2]) == 16.0 and float(h.aoi(16.0)[0, 1]) == 1.0
    h = signalling_update(h, 30.0, silent, state + 2, drop_after_missed=2)
    assert not h.neighbour_mask(2)[0, 2] and h.lost.tolist() == [True, True, False]
    assert torch.equal(h.state[0, 2], state[2])  # still the last state actually received
