"""The twin's perception step: a `CoverageEnv` observation -> `PolicyInputs`, batched over (B, N).

What every twin-side decision maker runs before its policy: the evaluation's
`LearnedController`, MAPPO's rollouts and validation, and imitation's DAgger rollouts. It
is what a deployed agent perceives (`deploy/agent/decision.py` builds the same
`PolicyInputs` from its messages, and the replay test checks both bit for bit):

* beliefs: the belief tracker replayed up to the observation time (`Beliefs.catch_up`);
* f: the failure state of the policy's rule (`PolicyForm.predicted_fail`): latched
  "predicted in range, yet silent" (`FailureFlags`), or the raw "a neighbour was dropped"
  of input version 1 (the twin's `fail_flag`);
* demand: the published map, one per environment, as a view per agent (version 2);
* target: the agent's point of the team plan (`plan.ServiceTargets`), for a policy that
  takes it, moved toward its sensed users by at most the mission's `track_sensed_m`
  (model/sensed_track.py; 0 by default: the plan point).

`obs` is any object with the fields of `plmarl_sitl.twin.env.Observation` (learning.nn does
not import the twin: tests/test_layers.py).
"""

from __future__ import annotations

import torch

from plmarl_sitl.learning.nn.belief import Beliefs, FailureFlags
from plmarl_sitl.learning.nn.contract import PolicyForm, PolicyInputs
from plmarl_sitl.learning.nn.plan import ServiceTargets
from plmarl_sitl.model.sensed_track import mission_toward_sensed


def plan_points(plan) -> tuple[torch.Tensor | None, torch.Tensor | None]:  # noqa: ANN001 - ServiceTargets | LocalTargets
    """(each agent's copy of the team plan's points (B, N, n, 2), each agent's identity (B, N)) for
    the sensed-users shift's link bound (model/sensed_track.py); (None, None) for the neighbourhood plan."""
    points = plan.copy_points() if isinstance(plan, ServiceTargets) else None
    if points is None:
        return None, None
    b, n = points.shape[:2]
    return points, torch.arange(n).expand(b, n)


class Perception:
    def __init__(self, tracker: torch.nn.Module, form: PolicyForm, r_comm: float, mission=None,  # noqa: ANN001 - Mission
                 sources: str = "plan") -> None:
        """`sources`: where the plan's failure re-plans assign from (`ServiceTargets`): "plan",
        the plan-aware prediction (the method's, common knowledge); "cv", each agent's held
        states dead-reckoned at constant velocity (the dead-reckoning ablation, whose tracker is
        constant velocity too)."""
        if form.takes_plan and mission is None:
            raise ValueError("a policy that takes the team plan needs the mission (its plan grid)")
        self.form = form
        self.mission = mission
        self.beliefs = Beliefs(tracker)
        self.flags = FailureFlags(r_comm)
        self.plan = ServiceTargets.of(mission, True, sources) if form.takes_plan else None
        self.point: torch.Tensor | None = None  # the policy's target input at the last call (B, N, 2)

    @property
    def plan_point(self) -> torch.Tensor | None:
        """(B, N, 2) the plan's own point at the last call (not moved toward the sensed users); None without a plan."""
        return None if self.plan is None else self.plan.last

    def reset(self) -> None:
        self.beliefs.reset()
        self.flags.reset()
        if self.plan is not None:
            self.plan.reset()

    @torch.no_grad()
    def __call__(self, obs) -> PolicyInputs:  # noqa: ANN001 - twin.env.Observation
        belief, _ = self.beliefs.catch_up(obs.t, obs.nbr_state, obs.nbr_t_rx)
        fail = self.flags.update(obs.nbr_mask, belief, obs.ego, obs.alive)  # latched every decision, whatever the form
        if not self.form.predicted_fail:
            fail = obs.fail_flag
        demand = target = None
        if self.form.takes_demand:
            demand = obs.demand.unsqueeze(1).expand(-1, obs.ego.shape[1], -1, -1)  # one map per environment
        if self.plan is not None:
            target = self.plan.update(obs.t, obs.ego, obs.nbr_state, obs.nbr_t_rx, obs.demand, mask=obs.nbr_mask,
                                      alive=obs.alive, gossip=obs.gossip)
            self.point = target = mission_toward_sensed(self.mission, target, obs.ego, obs.sense, lambda: plan_points(self.plan))
        return PolicyInputs(obs.ego, belief, obs.nbr_mask, obs.sense, fail, demand, target)
