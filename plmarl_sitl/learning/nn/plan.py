"""The team plan's targets for a batch of twin agents (model/service.py), from what each
agent observes: its own state and the states it received at the first signalling instant
(the launch line), and the published demand maps. The deployed agent runs the same
`TeamPlans` on its own messages (deploy/agent/plan.py)."""

from __future__ import annotations

import functools

import numpy as np
import torch

from plmarl_sitl.model.channel import CoverageRadius
from plmarl_sitl.model.demand import map_period
from plmarl_sitl.model.service import ServiceGrid, TeamPlans, grid_counts, launch_line
from plmarl_sitl.model.vehicle import goto_accel


def heard_launch(ego_xy: np.ndarray, held_xy: np.ndarray, heard: np.ndarray, me: int) -> np.ndarray:
    """One agent's launch line (n, 2): itself at ego_xy (2,), the neighbours it heard at the
    first instant (heard (n,) bool) at held_xy (n, 2)."""
    ids = [me] + [j for j in range(len(heard)) if heard[j] and j != me]
    pos = np.stack([ego_xy] + [held_xy[j] for j in ids[1:]])
    return launch_line(np.asarray(ids), pos, len(heard))


@functools.lru_cache(maxsize=8)
def _grid(area_n: float, area_e: float, cell_m: float, cover_r: float, comm_m: float, safe_m: float) -> ServiceGrid:
    return ServiceGrid(area_n, area_e, cell_m, cover_r, comm_m, safe_m)


def service_grid(mission) -> ServiceGrid:  # noqa: ANN001 - Mission
    """The mission's plan grid, built once per set of constants (it is a few MB of tables)."""
    vm = mission.vehicle_model()
    _, cover_r = CoverageRadius(mission.channel, mission.radii.sensing_m, vm.min_alt_m, vm.max_alt_m).best_altitude()
    return _grid(float(mission.area.north_m), float(mission.area.east_m), float(mission.demand.cell_m), float(cover_r),
                 float(mission.radii.comm_m), float(mission.radii.safe_m))


class ServiceTargets:
    """Per twin agent, the offset-free target (its plan point), (B, N, 2) metres."""

    def __init__(self, mission) -> None:  # noqa: ANN001 - Mission
        vm = mission.vehicle_model()
        self.alt, _ = CoverageRadius(mission.channel, mission.radii.sensing_m, vm.min_alt_m, vm.max_alt_m).best_altitude()
        self.grid = service_grid(mission)
        self.period = map_period(mission.demand.refresh_s, mission.timing.decision_every_s)
        self.v_max, self.a_max = float(vm.max_speed_mps), float(vm.max_accel_mps2)
        self.tau = float(mission.timing.decision_every_s)
        self.reset()

    @classmethod
    def of(cls, mission) -> ServiceTargets:  # noqa: ANN001 - Mission
        return cls(mission)

    def accel(self, ego: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        """Fly to the plan point `target` (..., 2) at the altitude of the largest coverage radius
        and stop there: the plan teacher of imitation, and `ServiceController`."""
        goal = torch.cat([target, torch.full_like(target[..., :1], -self.alt)], -1)
        return goto_accel(ego[..., :3], ego[..., 3:], goal, self.v_max, self.a_max, time_const=self.tau)

    def reset(self) -> None:
        self.plans: TeamPlans | None = None
        self.map_t = -1
        self.last: torch.Tensor | None = None  # the targets of the last update

    def update(self, t: int, ego: torch.Tensor, nbr_state: torch.Tensor, nbr_t_rx: torch.Tensor,
               demand: torch.Tensor) -> torch.Tensor:
        """Call at every decision: ego (B, N, 6), nbr_state (B, N, N, 6), nbr_t_rx (B, N, N), demand (B, K, 3)."""
        counts = np.stack([grid_counts(d, self.grid) for d in demand.double().numpy()])
        b, n = ego.shape[:2]
        if self.plans is None:
            ego_xy = ego[..., :2].double().numpy()
            held = nbr_state[..., :2].double().numpy()
            heard = (nbr_t_rx == float(t)).numpy()
            launch = np.stack([np.stack([heard_launch(ego_xy[e, i], held[e, i], heard[e, i], i) for i in range(n)])
                               for e in range(b)])
            self.plans = TeamPlans(self.grid, n)
            self.plans.start(launch, counts)
            self.map_t = t - t % self.period
        elif t - t % self.period != self.map_t:
            self.map_t = t - t % self.period
            self.plans.on_map(counts)
        self.last = torch.from_numpy(self.plans.targets(np.arange(n))).to(ego.dtype)
        return self.last

