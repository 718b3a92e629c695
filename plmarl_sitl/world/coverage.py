"""Coverage rate C(t) and the local user sensing an agent gets.

Definition used everywhere (twin, oracle, SITL world, evaluation): a ground user is
*covered* when at least one live UAV is within its coverage radius r_max(h) of it in
ground distance, where r_max(h) = min(R_s, r_PL(h)) and r_PL(h) is the ground distance
at which the mean Crowded-Urban A2G path loss reaches `channel.max_path_loss_db`.
C(t) is the covered share of all users.
"""

from __future__ import annotations

import torch

SENSING_SECTORS = 8
SENSING_FEATURES = 3 + SENSING_SECTORS  # count, centroid offset (2), sector counts


def covered_users(
    users_xy: torch.Tensor, uav_pos: torch.Tensor, alive: torch.Tensor, radius: torch.Tensor
) -> torch.Tensor:
    """Bool (..., U): covered by at least one live UAV.

    users_xy (..., U, 2); uav_pos (..., N, 3); alive (..., N); radius (..., N) metres.
    Works on squared distances only (no sqrt/log on the U x N path).
    """
    r2 = torch.where(alive, radius * radius, torch.full_like(radius, -1.0))
    covered = torch.zeros(users_xy.shape[:-1], dtype=torch.bool, device=users_xy.device)
    # A loop over N keeps the temporary at (..., U) instead of (..., U, N, 2).
    for k in range(uav_pos.shape[-2]):
        d = users_xy - uav_pos[..., k : k + 1, :2]
        d2 = d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1]
        covered |= d2 <= r2[..., k : k + 1]
    return covered


def coverage_rate(
    users_xy: torch.Tensor, uav_pos: torch.Tensor, alive: torch.Tensor, radius: torch.Tensor
) -> torch.Tensor:
    return covered_users(users_xy, uav_pos, alive, radius).float().mean(-1)


def sensing_features(
    uav_pos: torch.Tensor,
    users_xy: torch.Tensor,
    sensing_m: float,
    cluster_size: int,
    user_valid: torch.Tensor | None = None,
) -> torch.Tensor:
    """What an agent senses of the users within R_s of it, as a fixed-size vector.

    uav_pos (..., N, 3), users_xy (..., U, 2) -> (..., N, SENSING_FEATURES):
    [count / cluster_size, mean north offset / R_s, mean east offset / R_s,
     count per 45-degree sector / cluster_size (8)].
    The SITL agent calls this with the users its sensing topic lists, so the twin and
    the deployed agent see identical features. `user_valid` masks padding entries.
    """
    d = users_xy.unsqueeze(-3) - uav_pos[..., :2].unsqueeze(-2)  # (..., N, U, 2)
    dn, de = d[..., 0], d[..., 1]
    inside = dn * dn + de * de <= sensing_m * sensing_m
    if user_valid is not None:
        inside = inside & user_valid.unsqueeze(-2)
    w = inside.to(uav_pos.dtype)
    count = w.sum(-1)
    denom = torch.clamp(count, min=1.0)
    mean_n = (dn * w).sum(-1) / denom / sensing_m
    mean_e = (de * w).sum(-1) / denom / sensing_m
    # Sector index from signs and the larger axis: 8 wedges of 45 degrees, no atan2.
    sector = (dn >= 0).long() * 4 + (de >= 0).long() * 2 + (dn.abs() >= de.abs()).long()
    sectors = torch.zeros(*count.shape, SENSING_SECTORS, dtype=uav_pos.dtype, device=uav_pos.device)
    sectors.scatter_add_(-1, sector, w)
    feats = [count.unsqueeze(-1), mean_n.unsqueeze(-1), mean_e.unsqueeze(-1)]
    out = torch.cat(feats, dim=-1)
    out[..., 0] /= cluster_size
    return torch.cat([out, sectors / cluster_size], dim=-1)
