"""The plan follower's command, and where a learnt policy flies it: in transit.

`PlanFollower.accel` flies a UAV to its plan point at the altitude of the largest coverage
radius and stops there (`goto_accel` held for tau): what `service` flies, the imitation
teacher of the plan, and the motion the plan-aware prediction assumes for every teammate
(model/plan_motion.py).

`PlanFollower.in_transit` hands a learnt policy's UAV that command while it is more than the
mission's `transit_plan_m` from its plan point. Why: every survivor predicts its teammates as
flying their plan, and from those predictions it declares a silent teammate failed
(model/gossip.py) and assigns a re-plan's points (model/repairs.py, model/service.py). The
learnt policy steers in transit: on a far launch it flew a median 50 m and a 90th percentile
130 m off the nominal 30-60 s after take-off (docs/RESULTS.md, session 28), so a message
missed there became a false declaration of a live teammate, and a re-plan assigned points from
where nobody was. On station the policy decides. 300 m, the station radius of the local repairs
(model/repairs.py::STATION_M), is the distance measured to help (long strips, far launches) and
cost nothing elsewhere; at 50 m it also took over after each new map of walking crowds (their
points move 50-90 m), where the policy follows its crowd better. Off by default: with it the
learnt predictor no longer matters in transit (docs/RESULTS.md, session 28). The twin's
`LearnedController` and the deployed agent's `Decision` both call it, on the plan's own point
(not the one moved toward the sensed users).
"""

from __future__ import annotations

import torch

from plmarl_sitl.model.channel import mission_coverage
from plmarl_sitl.model.vehicle import goto_accel


class PlanFollower:
    def __init__(self, mission) -> None:  # noqa: ANN001 - Mission
        vm = mission.vehicle_model()
        self.alt, _ = mission_coverage(mission)
        self.v_max, self.a_max = float(vm.max_speed_mps), float(vm.max_accel_mps2)
        self.tau = int(mission.timing.decision_every_s)
        self.transit_m = float(mission.transit_plan_m)

    def accel(self, ego: torch.Tensor, point: torch.Tensor) -> torch.Tensor:
        """(..., 3) the command that flies ego (..., 6) to `point` (..., 2) at the plan altitude and stops there."""
        goal = torch.cat([point, torch.full_like(point[..., :1], -self.alt)], -1)
        return goto_accel(ego[..., :3], ego[..., 3:], goal, self.v_max, self.a_max, time_const=self.tau)

    def in_transit(self, accel: torch.Tensor, ego: torch.Tensor, point: torch.Tensor | None) -> torch.Tensor:
        """The policy's command `accel` (..., 3), or the plan follower's where ego (..., 6) is more
        than `transit_plan_m` (horizontally) from its plan point (..., 2); unchanged with 0 or no point."""
        if self.transit_m <= 0 or point is None:
            return accel
        point = point.to(ego.dtype)
        far = torch.linalg.vector_norm(ego[..., :2] - point, dim=-1, keepdim=True) > self.transit_m
        return torch.where(far, self.accel(ego, point).to(accel.dtype), accel)


__all__ = ["PlanFollower"]
