"""Communication graph and algebraic connectivity lambda_2.

A link i <-> j exists when both UAVs are alive, within R_comm, and the SINR is at least
Gamma in both directions. Edges are WEIGHTED by the link's spectral efficiency
w_ij = log2(1 + min(SINR_ij, SINR_ji)) [bit/s/Hz], so lambda_2 grows with link quality
as well as with the number of links (the paper's lambda_2 values above N = 4 for four
UAVs are only possible with weights above 1). `algebraic_connectivity` itself takes any
weighted adjacency; unit weights give the textbook values.
"""

from __future__ import annotations

import torch

from plmarl_sitl.mission import Channel
from plmarl_sitl.model.channel import db_to_lin, u2u_sinr


def link_mask(pos: torch.Tensor, alive: torch.Tensor, ch: Channel, comm_m: float) -> tuple[torch.Tensor, torch.Tensor]:
    """(directed receive mask [i, j]: i hears j, SINR (linear)) for (..., N, 3) positions."""
    sinr = u2u_sinr(pos, alive, ch)
    ok = (distances(pos) <= comm_m) & (sinr >= db_to_lin(ch.sinr_threshold_db))
    return ok, sinr


def weighted_adjacency(rx: torch.Tensor, sinr: torch.Tensor) -> torch.Tensor:
    both = rx & rx.transpose(-1, -2)
    w = torch.log2(1.0 + torch.minimum(sinr, sinr.transpose(-1, -2)))
    return torch.where(both, w, torch.zeros_like(w))


def algebraic_connectivity(adj: torch.Tensor, alive: torch.Tensor | None = None) -> torch.Tensor:
    """Second-smallest Laplacian eigenvalue of the live subgraph, shape (...,).

    Dead nodes are removed by giving them a huge isolated diagonal entry: their
    eigenvalue then sorts last and the rest of the spectrum is the live subgraph's.
    Fewer than two live nodes gives 0.
    """
    adj = adj.to(torch.float64)
    n = adj.shape[-1]
    if alive is None:
        alive = torch.ones(adj.shape[:-1], dtype=torch.bool, device=adj.device)
    adj = adj * (alive.unsqueeze(-1) & alive.unsqueeze(-2)).to(adj.dtype)  # dead nodes lose their edges
    lap = torch.diag_embed(adj.sum(-1)) - adj
    big = 1e9
    lap = lap + torch.diag_embed(torch.where(alive, 0.0, big).to(lap.dtype))
    eig = torch.linalg.eigvalsh(lap)
    n_alive = alive.sum(-1)
    lam2 = eig[..., 1] if n >= 2 else torch.zeros(adj.shape[:-2], dtype=adj.dtype)
    return torch.where(n_alive >= 2, torch.clamp(lam2, min=0.0), torch.zeros_like(lam2))


def distances(pos: torch.Tensor) -> torch.Tensor:
    """Exact pairwise distances (..., N, N); N is small, so no matmul shortcut."""
    return torch.linalg.vector_norm(pos.unsqueeze(-2) - pos.unsqueeze(-3), dim=-1)


def pairwise_separation(pos: torch.Tensor, alive: torch.Tensor) -> torch.Tensor:
    """Distance matrix with +inf on the diagonal and on pairs with a dead end."""
    dist = distances(pos)
    n = pos.shape[-2]
    eye = torch.eye(n, dtype=torch.bool, device=pos.device)
    pair = alive.unsqueeze(-1) & alive.unsqueeze(-2) & ~eye
    return torch.where(pair, dist, torch.full_like(dist, float("inf")))
