"""The plan point moved toward the users the UAV senses (mission `track_sensed_m`, issue 24.3).

Why: the team plan is placed on the demand map, which the ground network publishes every
`demand.refresh_s` (30 s) on 50 m cells. A crowd walking at 1.5-3 m/s is 50-90 m from its
map cell by the next map, and the plan point stays where the crowd was: a UAV watches its
users walk out of its coverage disk (docs/RESULTS.md, session 19). The UAV's own sensing
shows where its users are now: the centroid of the users within R_s
(`model/coverage.py::sensing_features`). Each UAV flies to its plan point shifted toward that
centroid by at most `track_sensed_m` metres, so it follows its crowd between maps while the
team plan still decides which crowd is whose.

The plan keeps the swarm connected: each point is within the link length (LINK_FRAC R_comm)
of another. Unbounded, a 30 m shift split the swarm (lambda_2 = 0) for about half of the
steady state on training seeds where the plan alone split it 6-9 % of the time, for two
reasons, each with its bound (both computed from the plan's points, which every copy holds
alike, so every agent computes the same bounds):

* shifts of two linked points add up: a point moves at most half the spare length of each of
  its edges in the minimum spanning tree of the plan's points (`tree_slack`);
* two UAVs whose plan points share one crowd (100 m apart) converge on its centroid and, 20-50 m
  apart, drown the team's other links in their interference (split with every distance under
  R_comm): points closer than 2 R_s in the plan do not move, the others never come closer than
  2 R_s (`spacing_slack`).

With both, the split share is the plan's own again (docs/RESULTS.md, session 19).

The twin (`learning/nn/perception.py`, `learning/eval/controllers.py`) and the deployed agent
(`deploy/agent/decision.py`) call `mission_toward_sensed` on the same sensing features, plan
point and plan points, so the point (and the policy input it is) is the same. 0 (the
default): the plan point.
"""

from __future__ import annotations

from collections.abc import Callable

import torch

from plmarl_sitl.model.service import LINK_FRAC


def spacing_slack(points: torch.Tensor, apart_m: float) -> torch.Tensor:
    """points (..., n, 2) float64 (NaN rows left out) -> (..., n): for each point, min over the
    other points of (distance - apart_m) / 2, at least 0 (inf alone). Two UAVs that converge on
    one crowd (two plan points 100 m apart, each shifted 30 m toward the crowd's centroid) sit
    20-50 m apart and drown the rest of the team's links in their interference (measured: the
    swarm split with every link distance under R_comm); points closer than apart_m in the plan
    do not move at all, the others not closer than apart_m."""
    valid = ~torch.isnan(points[..., 0])
    diff = points.unsqueeze(-2) - points.unsqueeze(-3)
    dist = torch.sqrt((diff * diff).sum(-1))
    n = points.shape[-2]
    other = valid.unsqueeze(-1) & valid.unsqueeze(-2) & ~torch.eye(n, dtype=torch.bool)
    half = torch.where(other, torch.clamp((dist - apart_m) / 2, min=0.0), torch.tensor(float("inf"), dtype=points.dtype))
    return half.amin(-1)


def tree_slack(points: torch.Tensor, link_m: float) -> torch.Tensor:
    """points (..., n, 2) float64 (NaN rows: failed identities, left out) -> (..., n): for each
    point, min over its edges in the minimum spanning tree of the points of (link_m - edge) / 2,
    at least 0 (inf for a point without edges). Prim's algorithm from the first live point,
    batched; ties go to the lowest index, so equal points give equal trees."""
    valid = ~torch.isnan(points[..., 0])
    diff = points.unsqueeze(-2) - points.unsqueeze(-3)
    dist = torch.sqrt((diff * diff).sum(-1))
    inf = torch.tensor(float("inf"), dtype=points.dtype)
    dist = torch.where(valid.unsqueeze(-1) & valid.unsqueeze(-2), dist, inf)
    n = points.shape[-2]
    slack = torch.full(points.shape[:-1], float("inf"), dtype=points.dtype)
    first = valid.to(torch.int8).argmax(-1, keepdim=True)  # the first live point
    in_tree = torch.zeros_like(valid).scatter(-1, first, True)
    best = torch.gather(dist, -2, first.unsqueeze(-1).expand(*first.shape, n)).squeeze(-2)  # (..., n)
    parent = first.expand_as(best).clone()
    for _ in range(n - 1):
        cand = torch.where(in_tree | ~valid, inf, best)
        k = cand.argmin(-1, keepdim=True)
        edge = torch.gather(cand, -1, k)  # inf where nothing is left to join
        joins = torch.isfinite(edge)
        half = torch.clamp((link_m - edge) / 2, min=0.0)
        half = torch.where(joins, half, inf)
        slack = slack.scatter_reduce(-1, k, half, "amin")
        slack = slack.scatter_reduce(-1, torch.gather(parent, -1, k), half, "amin")
        in_tree = in_tree.scatter(-1, k, joins | torch.gather(in_tree, -1, k))
        row = torch.gather(dist, -2, k.unsqueeze(-1).expand(*k.shape, n)).squeeze(-2)
        closer = joins & (row < best)
        parent = torch.where(closer, k.expand_as(parent), parent)
        best = torch.where(closer, row, best)
    return slack


class SlackCache:
    """`tree_slack` of the last points asked for. The plan's points change only at a new map or a
    re-plan (about every tenth decision), and the tree costs 0.4 ms at N = 4 and ~2 ms at N = 20
    per call on one agent's copy (docs/RESULTS.md, session 19); comparing the points costs microseconds."""

    def __init__(self) -> None:
        self.key: tuple[tuple[int, ...], float, bytes] | None = None
        self.slack: torch.Tensor | None = None

    def __call__(self, points: torch.Tensor, link_m: float, apart_m: float) -> torch.Tensor:
        key = (tuple(points.shape), link_m, apart_m, points.numpy().tobytes())
        if key != self.key or self.slack is None:
            self.key, self.slack = key, plan_slack(points, link_m, apart_m)
        return self.slack


def plan_slack(points: torch.Tensor, link_m: float, apart_m: float) -> torch.Tensor:
    """(..., n) how far each point may shift: `tree_slack` and `spacing_slack`, the smaller."""
    return torch.minimum(tree_slack(points, link_m), spacing_slack(points, apart_m))


def toward_sensed(target: torch.Tensor, ego_xy: torch.Tensor, sense: torch.Tensor, sensing_m: float,
                  max_m: float | torch.Tensor) -> torch.Tensor:
    """target (..., 2) plan point, ego_xy (..., 2), sense (..., SENSING_FEATURES) [count / cluster
    size, mean north offset / R_s, mean east offset / R_s, rms / R_s] -> (..., 2): the target
    moved toward the sensed users' centroid by at most max_m (a number, or (...) per point);
    unchanged where nothing is sensed."""
    if not isinstance(max_m, torch.Tensor) and max_m <= 0:
        return target
    limit = torch.as_tensor(max_m, dtype=target.dtype)
    if limit.dim():
        limit = limit.unsqueeze(-1)
    centroid = ego_xy + sense[..., 1:3] * sensing_m
    step = centroid - target
    dist = torch.sqrt((step * step).sum(-1, keepdim=True))
    step = step * torch.clamp(limit / torch.clamp(dist, min=1e-9), max=1.0)
    return torch.where((sense[..., :1] > 0), target + step, target)


Team = Callable[[], tuple[torch.Tensor | None, torch.Tensor | None]]


def mission_toward_sensed(mission, target: torch.Tensor, ego: torch.Tensor, sense: torch.Tensor,  # noqa: ANN001 - Mission
                          team: Team | None = None, cache: SlackCache | None = None) -> torch.Tensor:
    """`toward_sensed` with the mission's R_s and `track_sensed_m`; ego (..., >= 2) [north, east, ...].
    team() -> (points (..., n, 2), me (...)): the agent's copy of the plan's points (identity order,
    NaN: failed) and its identity; the shift is then also bounded by the plan's slack (`plan_slack`).
    It is called only when the shift is on (the copy costs a gather per call), and may give (None,
    None) (the neighbourhood plan, or before the plan starts): then only `track_sensed_m` bounds it.
    `cache` keeps the slack while the points stay the same (the same numbers as without)."""
    metres = float(mission.track_sensed_m)
    if metres <= 0:
        return target
    points, me = team() if team is not None else (None, None)
    if points is None or me is None:
        return toward_sensed(target, ego[..., :2], sense, float(mission.radii.sensing_m), metres)
    points = points.to(torch.float64)
    link_m = LINK_FRAC * float(mission.radii.comm_m)
    apart_m = 2.0 * float(mission.radii.sensing_m)  # coverage disks that did not overlap in the plan do not
    slack = plan_slack(points, link_m, apart_m) if cache is None else cache(points, link_m, apart_m)
    own = torch.gather(slack, -1, me.unsqueeze(-1)).squeeze(-1)
    bound = torch.clamp(own, max=metres)
    return toward_sensed(target, ego[..., :2], sense, float(mission.radii.sensing_m), bound)


__all__ = ["SlackCache", "Team", "mission_toward_sensed", "plan_slack", "spacing_slack", "toward_sensed", "tree_slack"]
