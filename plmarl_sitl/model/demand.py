"""The coarse user-density map: what an agent knows about demand beyond its own sensing.

A real deployment has it: the ground network (cell towers, the operator's user-location
service) counts users per coarse cell and publishes the map at mission start and then
rarely (`mission.demand.refresh_s`, 30 s). It is a grid of square cells of
`mission.demand.cell_m` (50 m) over the mission area, row-major from the south-west
corner (row = north index, column = east index); a user outside the area counts in the
nearest border cell.

The twin calls `demand_map` on its user positions; the SITL world calls the same
function and publishes the result (nonzero cells only) over MQTT. Agents turn the cells
into `demand_cells` (centre north, centre east, count) for the policy, which reduces
them to a fixed-size egocentric descriptor (plmarl_sitl/learning/nn/features.py).
Pure and batched; binning is a floor and a scatter (no transcendental function).
"""

from __future__ import annotations

import math

import torch

DEMAND_CELL_FIELDS = 3  # centre north (m), centre east (m), user count


def grid_shape(area_n: float, area_e: float, cell_m: float) -> tuple[int, int]:
    """(rows along north, columns along east) covering the area."""
    return max(1, math.ceil(area_n / cell_m - 1e-9)), max(1, math.ceil(area_e / cell_m - 1e-9))


def cell_centres(area_n: float, area_e: float, cell_m: float, dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """(K, 2) [north, east] centres of the K = rows * cols cells, row-major."""
    rows, cols = grid_shape(area_n, area_e, cell_m)
    n = (torch.arange(rows, dtype=torch.float64) + 0.5) * cell_m
    e = (torch.arange(cols, dtype=torch.float64) + 0.5) * cell_m
    return torch.stack(torch.meshgrid(n, e, indexing="ij"), -1).reshape(-1, 2).to(dtype)


def demand_map(
    users_xy: torch.Tensor, area_n: float, area_e: float, cell_m: float, user_valid: torch.Tensor | None = None
) -> torch.Tensor:
    """User counts per cell: users_xy (..., U, 2) -> (..., K) in users_xy's float dtype.

    `user_valid` (..., U) bool leaves users out (padding, or users already covered)."""
    rows, cols = grid_shape(area_n, area_e, cell_m)
    r = torch.clamp(torch.floor(users_xy[..., 0] / cell_m), 0, rows - 1).long()
    c = torch.clamp(torch.floor(users_xy[..., 1] / cell_m), 0, cols - 1).long()
    ones = torch.ones(r.shape, dtype=users_xy.dtype, device=users_xy.device)
    if user_valid is not None:
        ones = ones * user_valid.to(users_xy.dtype)
    out = torch.zeros(*r.shape[:-1], rows * cols, dtype=users_xy.dtype, device=users_xy.device)
    return out.scatter_add_(-1, r * cols + c, ones)


def map_period(refresh_s: float, decision_every_s: int) -> int:
    """Seconds between published maps. The twin refreshes at t = 0 and then at the first
    decision instant (a multiple of tau) at least `refresh_s` after the last map, so the
    maps fall on the multiples of this period; the SITL world publishes on the same
    seconds and an agent knows from it when a new map is due."""
    tau = int(decision_every_s)
    return tau * max(1, math.ceil(refresh_s / tau - 1e-9))


def is_map_instant(t: int, refresh_s: float, decision_every_s: int) -> bool:
    return t % map_period(refresh_s, decision_every_s) == 0


def demand_cells(counts: torch.Tensor, centres: torch.Tensor) -> torch.Tensor:
    """The policy's demand input: counts (..., K) and centres (K, 2) -> (..., K, 3)
    [centre north, centre east, count]. Any subset of cells (e.g. only the nonzero ones a
    message carries) is an equally valid input: empty cells add nothing."""
    c = centres.to(counts.dtype).expand(*counts.shape, 2)
    return torch.cat([c, counts.unsqueeze(-1)], -1)


__all__ = ["DEMAND_CELL_FIELDS", "cell_centres", "demand_cells", "demand_map", "grid_shape", "is_map_instant", "map_period"]
