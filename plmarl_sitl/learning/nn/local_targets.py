"""The neighbourhood plan's targets for a batch of twin agents (`coordination: local`,
model/local_plan.py): the twin's counterpart of `plan.ServiceTargets`, with its interface
(`update`, `accel`, `reset`), chosen by `ServiceTargets.of` when the mission says
`coordination: local`. The deployed agent runs the same `LocalPlan` on its own messages
(deploy/agent/local_plan.py)."""

from __future__ import annotations

import numpy as np
import torch

from plmarl_sitl.model.demand import map_period
from plmarl_sitl.model.local_plan import LocalPlan, heard_launch_line
from plmarl_sitl.model.plan_follower import PlanFollower
from plmarl_sitl.model.service import mission_launch_xy, plan_geometry


def local_plan_of(mission) -> LocalPlan:  # noqa: ANN001 - Mission
    """The mission's neighbourhood plan (its cells, coverage radius, R_comm, d_safe)."""
    return LocalPlan(*plan_geometry(mission))


class LocalTargets:
    """Per twin agent, its point of its own neighbourhood plan, (B, N, 2) metres: solved at
    the first decision and at each new map (every `demand.refresh_s`), held in between."""

    def __init__(self, mission) -> None:  # noqa: ANN001 - Mission
        self.follower = PlanFollower(mission)
        self.plan = local_plan_of(mission)
        self.nominal = mission_launch_xy(mission)  # the mission's launch line (model/service.py::launch_line)
        self.period = map_period(mission.demand.refresh_s, mission.timing.decision_every_s)
        self.reset()

    def accel(self, ego: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        """Fly to `target` (..., 2) at the altitude of the largest coverage radius and stop (as `ServiceTargets.accel`)."""
        return self.follower.accel(ego, target)

    def reset(self) -> None:
        self.map_t = -1
        self.last: torch.Tensor | None = None
        self.replans_done = 0

    def update(self, t: int, ego: torch.Tensor, nbr_state: torch.Tensor, nbr_t_rx: torch.Tensor,
               demand: torch.Tensor, *, mask: torch.Tensor | None = None, alive: torch.Tensor | None = None,
               gossip: object = None) -> torch.Tensor:
        """Call at every decision: ego (B, N, 6), nbr_state (B, N, N, 6), nbr_t_rx (B, N, N),
        demand (B, K, 3), mask (B, N, N) N_i (without: every neighbour ever heard)."""
        b, n = ego.shape[:2]
        if self.last is not None and t - t % self.period == self.map_t:
            return self.last
        self.map_t = t - t % self.period
        ego_np = ego[..., :2].double().numpy()
        held = nbr_state.double().numpy()
        t_rx = nbr_t_rx.double().numpy()
        m = (nbr_t_rx >= 0).numpy() if mask is None else mask.numpy()
        live = np.ones((b, n), dtype=bool) if alive is None else alive.numpy()
        cells = demand.double().numpy()
        out = np.full((b, n, 2), np.nan) if self.last is None else self.last.double().numpy().copy()
        first = self.last is None
        if first:
            self.memory = [[{} for _ in range(n)] for _ in range(b)]  # each agent's last plan: identity -> point
        for e in range(b):
            self.plan.set_map(cells[e][cells[e][:, 2] > 0])
            for a in range(n):
                if not live[e, a]:
                    continue
                own, rx = m[e, a].copy(), t_rx[e, a].copy()
                own[a], rx[a] = False, -1.0  # itself: from its own state (row 0)
                launch = heard_launch_line(ego_np[e, a], held[e, a, :, :2], t_rx[e, a] == float(t), a, self.nominal) if first else None
                pt = self.plan.solve(a, self.plan.team(a, ego_np[e, a], held[e, a], rx, own, float(t), self.memory[e][a], launch), self.memory[e][a])
                out[e, a] = ego_np[e, a] if pt is None else pt
        out = np.where(np.isnan(out), ego_np, out)
        self.last = torch.from_numpy(out).to(ego.dtype)
        return self.last
