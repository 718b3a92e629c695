"""Terms of the adaptive reward, Eq. (4):

    R(t) = w1 C(t) + w2(f) P(t) - w3(f) D(t) - w4 Psi_safe(t)

* C: coverage rate in [0, 1].
* P: potential, 1 - min(1, d / R_comm) where d is the ground distance between the
  network centre (mean of live UAVs) and the service centroid (mean of all users).
* D: mobility cost, sum over live UAVs of |v|^2 (m^2/s^2), a kinetic-energy proxy.
* Psi_safe: sum over live pairs closer than d_safe of (1 - d / d_safe)^2.

The weights switch from `pre_failure` to `post_failure` once the failure state f is set.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from plmarl_sitl.mission import Mission, RewardWeights
from plmarl_sitl.model.graph import pairwise_separation


@dataclass(frozen=True)
class RewardTerms:
    coverage: torch.Tensor
    potential: torch.Tensor
    mobility: torch.Tensor
    safety: torch.Tensor
    min_separation: torch.Tensor  # smallest live-pair distance (inf with < 2 live UAVs)


def reward_terms(
    coverage: torch.Tensor, uav_pos: torch.Tensor, uav_vel: torch.Tensor, alive: torch.Tensor,
    users_xy: torch.Tensor, mission: Mission,
) -> RewardTerms:
    a = alive.to(uav_pos.dtype)
    n_alive = torch.clamp(a.sum(-1, keepdim=True), min=1.0)
    net_centre = (uav_pos[..., :2] * a.unsqueeze(-1)).sum(-2) / n_alive
    service = users_xy.mean(-2)  # (B, U, 2) view of planar storage: a fast contiguous mean
    d = torch.linalg.vector_norm(net_centre - service, dim=-1)
    potential = 1.0 - torch.clamp(d / mission.radii.comm_m, max=1.0)
    mobility = ((uav_vel * uav_vel).sum(-1) * a).sum(-1)
    sep = pairwise_separation(uav_pos, alive)
    safe = mission.radii.safe_m
    if safe > 0:
        viol = torch.clamp(1.0 - sep / safe, min=0.0) ** 2
        safety = torch.triu(viol, diagonal=1).sum((-1, -2))
    else:
        safety = torch.zeros_like(coverage)
    return RewardTerms(coverage, potential, mobility, safety, sep.flatten(-2).min(-1).values)


def combine(terms: RewardTerms, failed: torch.Tensor, mission: Mission) -> torch.Tensor:
    """R(t) with weights chosen per environment by the failure state `failed` (bool)."""

    def r(w: RewardWeights) -> torch.Tensor:
        return w.coverage * terms.coverage + w.potential * terms.potential - w.mobility * terms.mobility - w.safety * terms.safety

    return torch.where(failed, r(mission.reward.post_failure), r(mission.reward.pre_failure))
