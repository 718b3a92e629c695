"""Attention fusion (Sec. III-B), the Gaussian actor and the centralised critic.

AttentionFusion, per agent i with neighbours j (masked to N_i):

    h_i      = tanh(E_ego(x_i))                      ego-state embedding
    h_hat_ij = Encoder(s_hat_ij) + PE(dp_ij)        dp_ij = p_hat_j - p_i (learnable PE)
    e_ij     = LeakyReLU(a^T [W h_i || W h_hat_ij])
    alpha_ij = softmax over j in N_i of e_ij        (0 neighbours -> all alpha = 0)
    m_i      = ELU(sum_j alpha_ij W h_hat_ij)       (0 neighbours -> m_i = 0)

The actor maps [h_i, m_i] to the mean of a Gaussian over the normalised acceleration
u in R^3 (tanh-bounded mean, state-independent std); the command sent is
A_max * clip(u, -1, 1) per axis, then the physics clips the norm to A_max.
"""

from __future__ import annotations

from typing import Optional

import torch
from torch import nn
from torch.nn import functional as F

from plmarl_sitl.learning.nn.contract import INPUT_VERSION, PolicyInputs
from plmarl_sitl.learning.nn.features import (
    DEMAND_FEATURES,
    EGO_FEATURES,
    NBR_FEATURES,
    REL_FEATURES,
    TOKEN_FEATURES,
    build_policy_input,
    map_blind_columns,
    ring_edges_sq,
)


def _ortho(layer: nn.Linear, gain: float = 2**0.5) -> nn.Linear:
    nn.init.orthogonal_(layer.weight, gain)
    if layer.bias is not None:
        nn.init.zeros_(layer.bias)
    return layer


class AttentionFusion(nn.Module):
    """Single-head GAT over the neighbour beliefs. Encoder and PE are linear maps, so
    h_hat_ij = Encoder(s_hat_ij) + PE(dp_ij) costs two small matmuls per agent; the
    attention vector a = [a1; a2] is applied as two dot products (same maths as
    a^T [W h_i || W h_hat_ij], without materialising the concatenation)."""

    def __init__(self, ego_dim: int = EGO_FEATURES, d: int = 32) -> None:
        super().__init__()
        self.d = d
        self.ego_enc = _ortho(nn.Linear(ego_dim, d))
        self.encoder = _ortho(nn.Linear(NBR_FEATURES, d))
        self.pe = _ortho(nn.Linear(REL_FEATURES, d), 1.0)
        self.W = _ortho(nn.Linear(d, d, bias=False), 1.0)
        self.a1 = nn.Parameter(torch.randn(d) / d**0.5)
        self.a2 = nn.Parameter(torch.randn(d) / d**0.5)

    def forward(
        self, ego_x: torch.Tensor, nbr_x: torch.Tensor, rel_x: torch.Tensor, mask: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """-> (h_i (..., d), m_i (..., d), alpha (..., M))."""
        h = torch.tanh(self.ego_enc(ego_x))
        # W (Encoder(s) + PE(dp)) is one linear map of [s, dp]; written so that a frozen file
        # holds the product as a constant (one matmul at run time, same parameters).
        w = self.W.weight
        whh = F.linear(
            torch.cat([nbr_x, rel_x], -1),
            w @ torch.cat([self.encoder.weight, self.pe.weight], 1),
            w @ (self.encoder.bias + self.pe.bias),
        )  # (..., M, d) = W h_hat_ij
        # (W h_i) . a1 = h_i . (W^T a1): a constant vector once the file is frozen.
        e = F.leaky_relu(whh @ self.a2 + (h @ (w.t() @ self.a1)).unsqueeze(-1), 0.2)
        alpha = torch.softmax(torch.where(mask, e, -1.0e9), -1)
        alpha = torch.where(mask, alpha, 0.0)  # all-masked rows: exactly 0, no NaN
        m = F.elu((alpha.unsqueeze(-2) @ whh).squeeze(-2))
        return h, m, alpha


class DemandAttention(nn.Module):
    """Scaled dot-product attention of the agent over the demand cells (tokens): the query
    comes from the ego embedding h_i, so the agent can point at one cell and read its exact
    offset back from the pooled value. Any number of cells; no cells -> a zero vector."""

    def __init__(self, d: int = 32) -> None:
        super().__init__()
        self.tok_enc = _ortho(nn.Linear(TOKEN_FEATURES, d))
        self.query = _ortho(nn.Linear(d, d, bias=False), 1.0)
        self.key = _ortho(nn.Linear(d, d, bias=False), 1.0)
        self.scale = 1.0 / d**0.5

    def forward(self, h: torch.Tensor, tok_x: torch.Tensor, tok_mask: torch.Tensor) -> torch.Tensor:
        v = torch.tanh(self.tok_enc(tok_x))  # (..., K, d)
        e = (self.key(v) @ self.query(h).unsqueeze(-1)).squeeze(-1) * self.scale  # (..., K)
        alpha = torch.softmax(torch.where(tok_mask, e, -1.0e9), -1)
        alpha = torch.where(tok_mask, alpha, 0.0)
        return F.elu((alpha.unsqueeze(-2) @ v).squeeze(-2))


class Actor(nn.Module):
    """reads_map=True: the ego features with the demand descriptor, and the demand attention
    over the map's cells. reads_map=False (a map-blind actor): the descriptor columns are
    dropped and there is no demand attention; the map reaches the agent only through the team
    plan's target (docs/POLICY_IO.md, "Map-blind policies"). The trained actors follow the
    plan either way, and the map's part is most of a decision's cost."""

    def __init__(self, d: int = 32, hidden: int = 64, log_std_init: float = -0.5, reads_map: bool = True) -> None:
        super().__init__()
        ego_dim = EGO_FEATURES if reads_map else EGO_FEATURES - DEMAND_FEATURES
        self.reads_map = reads_map
        self.fusion = AttentionFusion(ego_dim, d)
        self.demand = DemandAttention(d) if reads_map else None
        self.register_buffer("ego_cols", map_blind_columns(), persistent=False)
        self.trunk = nn.Sequential(
            _ortho(nn.Linear((3 if reads_map else 2) * d + ego_dim, hidden)), nn.Tanh(),
            _ortho(nn.Linear(hidden, hidden)), nn.Tanh(),
        )
        self.mu = _ortho(nn.Linear(hidden, 3), 0.01)
        self.log_std = nn.Parameter(torch.full((3,), log_std_init))

    def forward(self, ego_x: torch.Tensor, nbr_x: torch.Tensor, rel_x: torch.Tensor, mask: torch.Tensor,
                tok_x: torch.Tensor, tok_mask: torch.Tensor) -> torch.Tensor:
        """Mean of the normalised action u (..., 3), in (-1, 1)."""
        if self.demand is None:
            ego_x = ego_x.index_select(-1, self.ego_cols)
            h, m, _ = self.fusion(ego_x, nbr_x, rel_x, mask)
            return torch.tanh(self.mu(self.trunk(torch.cat([h, m, ego_x], -1))))
        h, m, _ = self.fusion(ego_x, nbr_x, rel_x, mask)
        md = self.demand(h, tok_x, tok_mask)
        return torch.tanh(self.mu(self.trunk(torch.cat([h, m, md, ego_x], -1))))

    def dist(self, ego_x: torch.Tensor, nbr_x: torch.Tensor, rel_x: torch.Tensor, mask: torch.Tensor,
             tok_x: torch.Tensor, tok_mask: torch.Tensor) -> torch.distributions.Normal:
        mean = self.forward(ego_x, nbr_x, rel_x, mask, tok_x, tok_mask)
        return torch.distributions.Normal(mean, self.log_std.exp().expand_as(mean))


class Critic(nn.Module):
    """Centralised V(s) on the twin's global state (one value per environment: the reward is shared)."""

    def __init__(self, state_dim: int, hidden: int = 128) -> None:
        super().__init__()
        self.net = nn.Sequential(
            _ortho(nn.Linear(state_dim, hidden)), nn.Tanh(), _ortho(nn.Linear(hidden, hidden)), nn.Tanh(), _ortho(nn.Linear(hidden, 1), 1.0)
        )

    def forward(self, s: torch.Tensor) -> torch.Tensor:
        return self.net(s).squeeze(-1)


def action_to_accel(u: torch.Tensor, a_max: float) -> torch.Tensor:
    return a_max * torch.clamp(u, -1.0, 1.0)


class DeployedPolicy(nn.Module):
    """What `policy.pt` is: raw physical inputs -> deterministic acceleration (m/s^2, NED).

    forward(ego (..., 6), beliefs (..., M, 6), mask (..., M) bool, sense (..., S),
    fail_flag (...) bool, demand (..., K, 3) or None, target (..., 2) or None) -> accel (..., 3). `demand` is None
    before the first map arrives (the descriptor is then zero, as for an empty map). The feature constants are
    attributes, so the file carries them (see docs/POLICY_IO.md, input version 2).
    """

    def __init__(self, actor: Actor, alt_max: float, v_max: float, a_max: float, r_comm: float, claim_m: float,
                 demand_unit: float) -> None:
        super().__init__()
        self.actor = actor
        self.alt_max, self.v_max, self.a_max, self.r_comm = float(alt_max), float(v_max), float(a_max), float(r_comm)
        self.claim_m, self.demand_unit = float(claim_m), float(demand_unit)
        self.input_version = INPUT_VERSION
        self.takes_plan = True  # called with the team-plan target (files without it: six inputs)
        self.reads_map = bool(actor.reads_map)  # False: `demand` is accepted and not read
        self.register_buffer("edges_sq", ring_edges_sq())

    def forward(
        self,
        ego: torch.Tensor,
        beliefs: torch.Tensor,
        mask: torch.Tensor,
        sense: torch.Tensor,
        fail_flag: torch.Tensor,
        demand: Optional[torch.Tensor] = None,  # noqa: UP045 - TorchScript needs Optional
        target: Optional[torch.Tensor] = None,  # noqa: UP045
    ) -> torch.Tensor:
        # The file keeps the positional forward (docs/POLICY_IO.md; callers use contract.PolicyCall).
        x = PolicyInputs(ego, beliefs, mask, sense, fail_flag, demand, target)
        ego_x, nbr_x, rel_x, m, tok_x, tok_m = build_policy_input(
            x, self.alt_max, self.v_max, self.r_comm, self.claim_m, self.demand_unit, self.edges_sq)
        return self.actor(ego_x, nbr_x, rel_x, m, tok_x, tok_m) * self.a_max  # tanh mean: already inside (-1, 1)
