"""The plan point moved toward the users the UAV senses (mission `track_sensed_m`, issue 24.3).

Why: the team plan is placed on the demand map, which the ground network publishes every
`demand.refresh_s` (30 s) on 50 m cells. A crowd walking at 1.8-3 m/s is 50-90 m from its
map cell by the next map, and the plan point stays where the crowd was: a UAV watches its
users walk out of its coverage disk (docs/RESULTS.md, session 19: -0.04..-0.14 of coverage
against a controller that sees the users). The UAV's own sensing shows where its users are
now: the centroid of the users within R_s (`model/coverage.py::sensing_features`). Each UAV
flies to its plan point shifted toward that centroid by at most `track_sensed_m` metres, so it
follows its crowd between maps while the team plan still decides which crowd is whose (the
bound keeps two UAVs from collapsing onto one crowd and the plan's links near their length).

The twin (`learning/nn/plan.py::ServiceTargets.point`) and the deployed agent
(`deploy/agent/decision.py`) call this one function on the same sensing features and plan
point, so the point (and the policy input it is) is the same. 0 (the default): the plan point.
"""

from __future__ import annotations

import torch


def toward_sensed(target: torch.Tensor, ego_xy: torch.Tensor, sense: torch.Tensor, sensing_m: float,
                  max_m: float) -> torch.Tensor:
    """target (..., 2) plan point, ego_xy (..., 2), sense (..., SENSING_FEATURES) [count / cluster
    size, mean north offset / R_s, mean east offset / R_s, rms / R_s] -> (..., 2): the target
    moved toward the sensed users' centroid by at most max_m; unchanged when nothing is sensed
    or max_m <= 0."""
    if max_m <= 0:
        return target
    centroid = ego_xy + sense[..., 1:3] * sensing_m
    step = centroid - target
    dist = torch.sqrt((step * step).sum(-1, keepdim=True))
    step = step * torch.clamp(max_m / torch.clamp(dist, min=1e-9), max=1.0)
    return torch.where((sense[..., :1] > 0), target + step, target)


def mission_toward_sensed(mission, target: torch.Tensor, ego: torch.Tensor, sense: torch.Tensor) -> torch.Tensor:  # noqa: ANN001 - Mission
    """`toward_sensed` with the mission's R_s and `track_sensed_m`; ego (..., >= 2) [north, east, ...]."""
    return toward_sensed(target, ego[..., :2], sense, float(mission.radii.sensing_m), float(mission.track_sensed_m))


__all__ = ["mission_toward_sensed", "toward_sensed"]
