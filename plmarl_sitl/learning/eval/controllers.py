"""Learnt policies as twin `Controller`s (`reset()`, `act(obs) -> accel`), deterministic.

A LearnedController runs exactly what a deployed agent runs: the belief tracker once per
physics second (replayed up to the observation time, see `Beliefs.catch_up`) and the
exported policy on the raw physical tensors, batched over the twin's (B, N) agents; the
failure flag f by the predicted-in-range rule (`FailureFlags`), the demand map as published.
A policy of input version 1 gets neither the map nor that rule (its raw flag, as it was trained).
"""

from __future__ import annotations

import torch
from torch import nn

from plmarl_sitl.learning.nn.belief import Beliefs, FailureFlags
from plmarl_sitl.learning.nn.io import input_version, takes_plan
from plmarl_sitl.learning.nn.plan import ServiceTargets
from plmarl_sitl.twin.env import Observation


class LearnedController:
    def __init__(self, tracker: nn.Module, policy: nn.Module, mission=None) -> None:  # noqa: ANN001 - Mission
        self.beliefs = Beliefs(tracker)
        if takes_plan(policy) and mission is None:
            raise ValueError("a policy that takes the team plan needs the mission (its plan grid)")
        self.plan = ServiceTargets.of(mission) if takes_plan(policy) else None
        self.flags = FailureFlags(float(policy.r_comm))
        self.policy = policy
        self.version = input_version(policy)  # 1: the policies shipped before issue 12 (no map, raw f)

    def reset(self) -> None:
        self.beliefs.reset()
        self.flags.reset()
        if self.plan is not None:
            self.plan.reset()

    @torch.no_grad()
    def act(self, obs: Observation) -> torch.Tensor:
        belief, _ = self.beliefs.catch_up(obs.t, obs.nbr_state, obs.nbr_t_rx)
        fail = self.flags.update(obs.nbr_mask, belief, obs.ego, obs.alive)
        if self.version < 2:
            return self.policy(obs.ego, belief, obs.nbr_mask, obs.sense, obs.fail_flag)
        demand = obs.demand.unsqueeze(1).expand(-1, obs.ego.shape[1], -1, -1)  # one map per environment
        if self.plan is None:
            return self.policy(obs.ego, belief, obs.nbr_mask, obs.sense, fail, demand)
        target = self.plan.update(obs.t, obs.ego, obs.nbr_state, obs.nbr_t_rx, obs.demand, mask=obs.nbr_mask,
                                  alive=obs.alive, gossip=obs.gossip)
        return self.policy(obs.ego, belief, obs.nbr_mask, obs.sense, fail, demand, target)


class ServiceController:
    """Not learnt: every agent flies to its point of the team plan (model/service.py) at the
    altitude of the largest coverage radius. What implicit coordination alone achieves.
    With `replan` (the default) the plan is re-solved at failures from the gossiped
    knowledge (model/gossip.py); without, it is today's plan fixed at t = 0 and new maps."""

    def __init__(self, mission, replan: bool = True, sources: str = "plan") -> None:  # noqa: ANN001 - Mission
        self.mission = mission
        self.targets = ServiceTargets.of(mission, replan, sources)

    def reset(self) -> None:
        self.targets.reset()

    @torch.no_grad()
    def act(self, obs: Observation) -> torch.Tensor:
        xy = self.targets.update(obs.t, obs.ego, obs.nbr_state, obs.nbr_t_rx, obs.demand, mask=obs.nbr_mask,
                                 alive=obs.alive, gossip=obs.gossip)
        return self.targets.accel(obs.ego, xy)
