"""Neighbour trajectories from the twin, for training and scoring the predictors.

UAV trajectories (true [p, v] every physics second) are recorded under a mix of
controllers, each run on the mixed-mobility curriculum (RWP, GM, RPGM users):

* `oracle`    the greedy reference (twin/greedy.py; its key keeps the old name "the Oracle"; global
              knowledge, purposeful flight to cluster sites)
* `heuristic` the decentralised heuristic (seek users, explore, keep links)
* `waypoint`  random waypoints in the area and altitude band, random cruise speed
* `ou`        Ornstein-Uhlenbeck random accelerations (smooth random manoeuvres)
* `policy`    any callable obs -> accel, e.g. a trained actor (used for fine-tuning)
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable

import torch

from plmarl_sitl.learning.train.seeds import training_twin_seed
from plmarl_sitl.mission import Mission
from plmarl_sitl.model.vehicle import velocity_tracking_accel
from plmarl_sitl.twin.env import CoverageEnv, Observation

CONTROLLERS = ("oracle", "heuristic", "waypoint", "ou")


def mixed_mobility(mission: Mission) -> Mission:
    return dataclasses.replace(mission, users=dataclasses.replace(mission.users, mobility="mixed"))


class _Waypoint:
    def __init__(self, env: CoverageEnv, gen: torch.Generator) -> None:
        self.env, self.gen = env, gen
        b, n = env.num_envs, env.n
        self.target = torch.zeros(b, n, 3)
        self.speed = torch.zeros(b, n, 1)
        self._new(torch.ones(b, n, dtype=torch.bool))

    def _new(self, which: torch.Tensor) -> None:
        m, vm = self.env.mission, self.env.vehicle
        b, n = which.shape
        r = torch.rand(b, n, 4, generator=self.gen)
        tgt = torch.stack([r[..., 0] * m.area.north_m, r[..., 1] * m.area.east_m, -(vm.min_alt_m + r[..., 2] * (vm.max_alt_m - vm.min_alt_m))], -1)
        self.target = torch.where(which.unsqueeze(-1), tgt, self.target)
        self.speed = torch.where(which.unsqueeze(-1), (2.0 + r[..., 3:4] * (vm.max_speed_mps - 2.0)), self.speed)

    def act(self, obs: Observation) -> torch.Tensor:
        p, v = obs.ego[..., :3], obs.ego[..., 3:]
        d = self.target - p
        dist = torch.linalg.vector_norm(d, dim=-1, keepdim=True)
        self._new(dist.squeeze(-1) < 15.0)
        d = self.target - p
        dist = torch.linalg.vector_norm(d, dim=-1, keepdim=True)
        v_des = d / torch.clamp(dist, min=1e-6) * torch.minimum(self.speed, 0.3 * dist)
        return velocity_tracking_accel(v, v_des, self.env.vehicle.max_accel_mps2, time_const=2.0)


class _OU:
    def __init__(self, env: CoverageEnv, gen: torch.Generator) -> None:
        self.env, self.gen = env, gen
        self.a = torch.zeros(env.num_envs, env.n, 3)

    def act(self, obs: Observation) -> torch.Tensor:
        amax = self.env.vehicle.max_accel_mps2
        self.a = 0.7 * self.a + 0.7 * amax * torch.randn(self.a.shape, generator=self.gen)
        # Keep away from the walls of the area: steer back in when close.
        p = obs.ego[..., :3]
        m = self.env.mission
        lo = torch.tensor([50.0, 50.0, -140.0])
        hi = torch.tensor([m.area.north_m - 50.0, m.area.east_m - 50.0, -50.0])
        back = torch.clamp(lo - p, min=0.0) * 0.2 - torch.clamp(p - hi, min=0.0) * 0.2
        return torch.clamp(self.a + back - 0.2 * obs.ego[..., 3:], -amax, amax)


def record(
    mission: Mission,
    controller: str,
    episodes: int,
    seed: int,
    policy: Callable[[Observation], torch.Tensor] | None = None,
    failure_prob: float = 0.0,
) -> tuple[torch.Tensor, torch.Tensor]:
    """-> (traj (E, N, T+1, 6) true states at t = 0..T, alive (E, N, T+1) bool)."""
    env = CoverageEnv(mission, episodes, training_twin_seed(seed), failure_prob=failure_prob)
    gen = torch.Generator().manual_seed(seed + 7919)
    if controller == "oracle":
        from plmarl_sitl.twin.greedy import GreedyController

        ctl: object = GreedyController(env)
    elif controller == "heuristic":
        from plmarl_sitl.twin.heuristic import HeuristicController

        ctl = HeuristicController(env.mission)
    elif controller == "waypoint":
        ctl = _Waypoint(env, gen)
    elif controller == "ou":
        ctl = _OU(env, gen)
    elif controller == "policy":
        if policy is None:
            raise ValueError("controller 'policy' needs policy=")
        ctl = None
    else:
        raise ValueError(f"unknown controller {controller!r}")
    if hasattr(ctl, "reset"):
        ctl.reset()  # type: ignore[union-attr]
    states, alive = [env.true_state().clone()], [env.alive.clone()]
    k = mission.timing.decision_every_s
    obs = env.observe()
    while not env.done:
        accel = policy(obs) if ctl is None else ctl.act(obs)  # type: ignore[union-attr]
        for _ in range(min(k, env.horizon - env.t)):
            env.physics_step(accel)
            states.append(env.true_state().clone())
            alive.append(env.alive.clone())
        obs = env.observe()
    return torch.stack(states, 2), torch.stack(alive, 2)
