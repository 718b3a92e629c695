"""This agent's copy of the team plan (model/service.py): its own point, from the launch
line it heard at its first decision and the demand maps it received.

The twin's controllers run the same `TeamPlans` (learning/nn/plan.py::ServiceTargets) on
the same information, so the agent's target equals its twin's: the plan starts at the first
decision that has a map, from the states received at the first decision (the launch line;
the decision at the first instant waits for every neighbour), and follows each new map
when a decision first uses it.
"""

from __future__ import annotations

import numpy as np
import torch

from plmarl_sitl.learning.nn.plan import heard_launch, service_grid
from plmarl_sitl.mission import Mission
from plmarl_sitl.model.service import TeamPlans, grid_counts


class AgentPlan:
    def __init__(self, mission: Mission, me: int) -> None:
        self.me, self.n = me, mission.n_uavs
        self.grid = service_grid(mission)
        self.plans = TeamPlans(self.grid, self.n)
        self.launch: np.ndarray | None = None  # (n, 2) the launch line as heard at the first decision
        self.map_t: float | None = None  # snapshot time of the map the plan follows
        self.started = False

    def target(self, k: int, ego: torch.Tensor, held: torch.Tensor, t_rx: torch.Tensor,
               demand: tuple[float, torch.Tensor] | None) -> torch.Tensor | None:
        """At a decision at second k: (2,) float32 north, east of this agent's point, or None
        before a map has arrived. held (n, 6) / t_rx (n,): the neighbour table."""
        if self.launch is None:
            heard = (t_rx == float(k)).numpy()
            heard[self.me] = False
            self.launch = heard_launch(ego[:2].double().numpy(), held[:, :2].double().numpy(), heard, self.me)
        if demand is None:
            return None
        t_map, cells = demand
        counts = grid_counts(cells.double().numpy(), self.grid)[None]
        if not self.started:
            self.plans.start(self.launch[None, None], counts)
            self.started = True
        elif t_map != self.map_t:
            self.plans.on_map(counts)
        self.map_t = t_map
        return torch.from_numpy(self.plans.targets(np.array([self.me]))[0, 0]).to(torch.float32)
