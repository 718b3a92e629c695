"""This agent's point of its neighbourhood plan (`coordination: local`, model/local_plan.py):
the counterpart of `plan.AgentPlan` for a mission that says `coordination: local`, with its
`target` interface (deploy/agent/decision.py calls whichever `coordination.agent_plan`
returns). Solved at the first decision with a map and at each new map, from the agent's own
state and its neighbours in N_i (held states dead-reckoned), as the twin's
`learning/nn/local_targets.py::LocalTargets`; in between a decision only looks it up."""

from __future__ import annotations

import numpy as np
import torch

from plmarl_sitl.learning.nn.local_targets import local_plan_of
from plmarl_sitl.mission import Mission
from plmarl_sitl.model.gossip import Knowledge
from plmarl_sitl.model.local_plan import heard_launch_line
from plmarl_sitl.model.service import mission_launch_xy


class LocalAgentPlan:
    def __init__(self, mission: Mission, me: int, knowledge: Knowledge | None = None) -> None:
        self.me, self.n = me, mission.n_uavs
        self.plan = local_plan_of(mission)
        self.nominal = mission_launch_xy(mission)  # the mission's launch line (model/service.py::launch_line)
        self.knowledge = knowledge if knowledge is not None else Knowledge(me)  # carried on the wire; not used to plan
        self.map_t: float | None = None
        self.point: torch.Tensor | None = None
        self.memory: dict[int, np.ndarray] = {}  # its last plan: identity -> point

    def target(self, k: int, ego: torch.Tensor, held: torch.Tensor, t_rx: torch.Tensor,
               demand: tuple[float, torch.Tensor] | None, mask: torch.Tensor | None = None) -> torch.Tensor | None:
        """At a decision at second k: (2,) float32 north, east of this agent's point, or None
        before a map has arrived. held (n, 6) / t_rx (n,): the neighbour table; mask (n,) N_i
        (without: every neighbour ever heard)."""
        if demand is None:
            return None
        t_map, cells = demand
        if self.point is not None and t_map == self.map_t:
            return self.point
        self.map_t = t_map
        self.plan.set_map(cells.double().numpy())
        rx = t_rx.double().numpy()
        own = (rx >= 0) if mask is None else mask.numpy().astype(bool)
        own, rx = own.copy(), rx.copy()
        own[self.me], rx[self.me] = False, -1.0  # itself: from its own state (row 0)
        ego_xy = ego[:2].double().numpy()
        held_np = held.double().numpy()
        # the first plan: the teammates not heard yet on the launch line fitted through those heard (as the team plan)
        launch = heard_launch_line(ego_xy, held_np[:, :2], rx == float(k), self.me, self.nominal) if self.point is None else None
        pt = self.plan.solve(self.me, self.plan.team(self.me, ego_xy, held_np, rx, own, float(k), self.memory, launch), self.memory)
        self.point = torch.from_numpy(np.asarray(ego_xy if pt is None else pt, dtype=np.float64)).to(torch.float32)
        return self.point
