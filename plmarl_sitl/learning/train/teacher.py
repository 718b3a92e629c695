"""A CTDE teacher that reacts at once: the team plan re-solved the second a UAV fails, from the
true positions of the survivors (training only; the student sees only its own beliefs).

Why: the plan follower `service` (and a student imitating it) learns of a failure only from
missed signalling instants (`drop_after_missed` of them, then gossip hops): 30-100 s at
T_up 15-50. In the twin a teacher may know the failure and every teammate's state (the
letter's centralised training). Its action is "fly to your point of the plan re-solved for the
true failed set at the failure, assigned by least travel from where the survivors really
are". A student that imitates it sees only what it would see deployed (its beliefs with their
ages, the failure flag f "predicted in range, yet silent", its own plan point), so whatever it
learns of reacting before the declaration it must infer from those.
"""

from __future__ import annotations

import numpy as np
import torch

from plmarl_sitl.learning.nn.plan import ServiceTargets
from plmarl_sitl.model.gossip import Gossip


class ReactTargets(ServiceTargets):
    """`ServiceTargets` whose failure knowledge is the twin's truth: every copy re-plans at the
    first decision a UAV is dead, for epoch = that second, from the true positions."""

    def update_true(self, obs) -> torch.Tensor:  # noqa: ANN001 - twin.env.Observation
        """The teacher's targets (B, N, 2) at this decision."""
        if self.plans is None:  # the plan-aware motion (which a re-plan replays) needs a gossip at the first call
            gossip = Gossip(obs.ego.shape[0], obs.ego.shape[1])
        else:
            gossip = obs.gossip
        return self.update(obs.t, obs.ego, obs.nbr_state, obs.nbr_t_rx, obs.demand, mask=obs.nbr_mask,
                           alive=obs.alive, gossip=gossip)

    def on_failures(self, t: int, mask: torch.Tensor, alive: torch.Tensor, gossip: Gossip, t_rx: torch.Tensor,
                    ego: torch.Tensor, held: torch.Tensor) -> None:
        plans = self.plans
        assert plans is not None and plans.motion is not None
        dead = ~alive.numpy()  # (B, N)
        live = alive.numpy()
        stale = live & (plans.failed != dead[:, None, :]).any(-1)
        true_xy = ego[..., :2].double().numpy()  # (B, N, 2): every identity's true position
        for e, a in zip(*np.nonzero(stale), strict=True):
            plans.replan(int(e), int(a), dead[e].copy(), int(t), true_xy[e])
            self.replans_done += 1


__all__ = ["ReactTargets"]
