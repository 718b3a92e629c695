"""Learnt policies as twin `Controller`s (`reset()`, `act(obs) -> accel`), deterministic.

A LearnedController runs exactly what a deployed agent runs, batched over the twin's (B, N)
agents: the perception step (`learning/nn/perception.py`: the belief tracker replayed up to
the observation time, the failure flag f of the policy's rule, the demand map as published,
the team plan's point) and the exported policy through the typed call
(`learning/nn/contract.py::PolicyCall`, which passes each file the inputs of its version).
"""

from __future__ import annotations

import torch
from torch import nn

from plmarl_sitl.learning.nn.contract import PolicyCall
from plmarl_sitl.learning.nn.perception import Perception, plan_points
from plmarl_sitl.learning.nn.plan import ServiceTargets
from plmarl_sitl.model.gossip import DECLARE_AFTER_MISSED
from plmarl_sitl.model.plan_follower import PlanFollower
from plmarl_sitl.model.sensed_track import mission_toward_sensed
from plmarl_sitl.twin.env import Observation


class LearnedController:
    def __init__(self, tracker: nn.Module, policy: nn.Module, mission=None, sources: str = "plan") -> None:  # noqa: ANN001 - Mission
        self.policy = PolicyCall(policy)
        self.perceive = Perception(tracker, self.policy.form, float(policy.r_comm), mission, sources)
        # in transit (the mission's transit_plan_m from the plan point) the plan follower's command
        self.follower = PlanFollower(mission) if mission is not None else None

    def reset(self) -> None:
        self.perceive.reset()

    @torch.no_grad()
    def act(self, obs: Observation) -> torch.Tensor:
        accel = self.policy(self.perceive(obs))
        if self.follower is None:
            return accel
        return self.follower.in_transit(accel, obs.ego, self.perceive.plan_point)


class ServiceController:
    """Not learnt: every agent flies to its point of the team plan (model/service.py) at the
    altitude of the largest coverage radius. What implicit coordination alone achieves.
    With `replan` (the default) the plan is re-solved at failures from the gossiped
    knowledge (model/gossip.py); without, it is today's plan fixed at t = 0 and new maps.
    With the mission's `track_sensed_m` the point moves toward the users the UAV senses
    (model/sensed_track.py)."""

    def __init__(self, mission, replan: bool = True, sources: str = "plan",  # noqa: ANN001 - Mission
                 declare_after: int = DECLARE_AFTER_MISSED) -> None:
        self.mission = mission
        self.targets = ServiceTargets.of(mission, replan, sources, declare_after)

    def reset(self) -> None:
        self.targets.reset()

    @torch.no_grad()
    def act(self, obs: Observation) -> torch.Tensor:
        xy = self.targets.update(obs.t, obs.ego, obs.nbr_state, obs.nbr_t_rx, obs.demand, mask=obs.nbr_mask,
                                 alive=obs.alive, gossip=obs.gossip)
        return self.targets.accel(obs.ego, mission_toward_sensed(self.mission, xy, obs.ego, obs.sense,
                                                                  lambda: plan_points(self.targets)))
