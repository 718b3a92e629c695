"""Greedy clairvoyant placement (method `greedy`; called "the Oracle" before issue 24):
sequential greedy grid search with global knowledge.

Every decision it sees every user and every UAV (no signalling, no staleness) and:
1. places live UAVs one at a time on a grid at the altitude with the largest coverage
   radius, each on the cell that covers the most still-uncovered users, restricted to
   cells within `link_frac * R_comm` of a UAV already placed (the swarm stays connected)
   and at least 2 d_safe from them;
2. assigns placements to UAVs with the least total travel (Hungarian method);
3. flies there with the same point-mass dynamics as everyone else.

A new plan replaces the current one only when it covers more users (or a UAV died), so
the swarm does not chase ties. It still pays the flight time from the launch point, like
every policy. It is a reference, NOT a bound: a greedy placement is not optimal, and the plan
follower `service` beats it by 1-3 % on several suite families (docs/RESULTS.md, issue 24).
`twin/clairvoyant.py` is the stronger reference, and the reports take the best of them.
"""

from __future__ import annotations

import numpy as np
import torch
from scipy.optimize import linear_sum_assignment

from plmarl_sitl.model.vehicle import goto_accel
from plmarl_sitl.twin.env import CoverageEnv, Observation

_CHUNK = 16  # environments per (B, cells, users) block: bounds memory at large batches


class GreedyController:
    def __init__(self, env: CoverageEnv, grid_m: float = 25.0, link_frac: float = 0.95) -> None:
        self.env = env
        m = env.mission
        self.alt, self.r = env.radius.best_altitude()
        n_axis = torch.arange(0.0, m.area.north_m + 1e-9, grid_m)
        e_axis = torch.arange(0.0, m.area.east_m + 1e-9, grid_m)
        self.cells = torch.cartesian_prod(n_axis, e_axis).to(env.dtype)  # (C, 2)
        cd = torch.cdist(self.cells.double(), self.cells.double())
        self.link_ok = cd <= link_frac * m.radii.comm_m  # (C, C) cell pairs that stay linked
        self.apart_ok = cd >= 2.0 * m.radii.safe_m
        self.reset()

    def reset(self) -> None:
        self.targets: torch.Tensor | None = None  # (B, N, 2)
        self._alive: torch.Tensor | None = None

    def _cover_matrix(self, users: torch.Tensor) -> torch.Tensor:
        """(b, C, U) float: 1 where the cell covers the user (squared distances only)."""
        c2 = (self.cells * self.cells).sum(-1)
        u2 = (users * users).sum(-1)
        d2 = c2[None, :, None] + u2[:, None, :] - 2.0 * torch.einsum("cd,bud->bcu", self.cells, users)
        return (d2 <= self.r * self.r).to(users.dtype)

    def plan(self, users: torch.Tensor, n_place: int) -> tuple[torch.Tensor, torch.Tensor]:
        """Greedy placements (b, n_place, 2) and users they cover (b,) for users (b, U, 2)."""
        cov = self._cover_matrix(users)
        b = users.shape[0]
        uncovered = torch.ones(b, users.shape[1], dtype=users.dtype)
        n_cells = self.cells.shape[0]
        near = torch.zeros(b, n_cells, dtype=torch.bool)  # within link range of a placed UAV
        apart = torch.ones(b, n_cells, dtype=torch.bool)  # far enough from every placed UAV
        allowed = torch.ones(b, n_cells, dtype=torch.bool)
        chosen = []
        for _ in range(n_place):
            gain = torch.einsum("bcu,bu->bc", cov, uncovered)
            gain = torch.where(allowed, gain, torch.full_like(gain, -1.0))
            best = gain.argmax(-1)  # (b,) ties go to the lowest cell index: deterministic
            chosen.append(best)
            uncovered = uncovered * (1.0 - cov[torch.arange(b), best])
            near = near | self.link_ok[best]
            apart = apart & self.apart_ok[best]
            allowed = near & apart
        idx = torch.stack(chosen, -1)
        covered = users.shape[1] - uncovered.sum(-1)
        return self.cells[idx], covered

    def _covered_by(self, users: torch.Tensor, targets: torch.Tensor, live: torch.Tensor) -> torch.Tensor:
        d2 = ((users.unsqueeze(-2) - targets.unsqueeze(-3)) ** 2).sum(-1)  # (b, U, N)
        hit = (d2 <= self.r * self.r) & live.unsqueeze(-2)
        return hit.any(-1).sum(-1).to(users.dtype)

    def _assign(self, targets: torch.Tensor, e: int, users: torch.Tensor, placements: torch.Tensor) -> None:
        """Write into targets[e] the placements assigned to environment e's live UAVs with the
        least total travel (Hungarian); with fewer live UAVs, re-plan for exactly that many."""
        env = self.env
        live = torch.nonzero(env.alive[e]).flatten()
        k = len(live)
        if k == 0:
            return
        places = placements if k == env.n else self.plan(users, k)[0][0]
        cost = torch.cdist(env.pos[e, live, :2].double(), places.double()).numpy()
        rows, cols = linear_sum_assignment(cost)
        targets[e, live[rows]] = places[torch.from_numpy(np.asarray(cols))]

    def act_from_state(self, obs: Observation) -> torch.Tensor:
        """The greedy's action from the current state alone, for imitation labels.

        `act` keeps its plan (it re-plans only for more users or a death), so once a
        student has flown elsewhere `act` still sends every UAV to the slot it was given at
        launch: a label that no local observation explains. Here today's greedy placements
        are assigned to the live UAVs where they are now (Hungarian), with no memory.
        """
        env = self.env
        b, n = env.num_envs, env.n
        targets = env.pos[..., :2].clone()
        for lo in range(0, b, _CHUNK):
            sl = slice(lo, min(b, lo + _CHUNK))
            users = env.users.xy[sl]
            placements, _ = self.plan(users, n)
            for j in range(sl.stop - sl.start):
                self._assign(targets, lo + j, users[j : j + 1], placements[j])
        target = torch.cat([targets, torch.full((b, n, 1), -self.alt, dtype=env.dtype)], -1)
        tau = float(env.mission.timing.decision_every_s)
        return goto_accel(env.pos, env.vel, target, env.limits.max_speed, env.limits.max_accel, time_const=tau)

    def act(self, obs: Observation) -> torch.Tensor:
        env = self.env
        targets = self.plan_targets()
        target = torch.cat([targets, torch.full((env.num_envs, env.n, 1), -self.alt, dtype=env.dtype)], -1)
        tau = float(env.mission.timing.decision_every_s)
        return goto_accel(env.pos, env.vel, target, env.limits.max_speed, env.limits.max_accel, time_const=tau)

    def plan_targets(self) -> torch.Tensor:
        """(B, N, 2) every UAV's target after this decision's re-plan (new plans only when they
        cover more users, or a UAV died). The clairvoyant reference reads it as a candidate."""
        env = self.env
        b = env.num_envs
        alive = env.alive
        if self.targets is None:
            self.targets = env.pos[..., :2].clone()
            self._alive = torch.zeros_like(alive)
        for lo in range(0, b, _CHUNK):
            sl = slice(lo, min(b, lo + _CHUNK))
            users = env.users.xy[sl]
            placements, gain = self.plan(users, env.n)
            current = self._covered_by(users, self.targets[sl], alive[sl])
            replan = (gain > current) | (alive[sl] != self._alive[sl]).any(-1)
            for j in torch.nonzero(replan).flatten().tolist():
                self._assign(self.targets, lo + j, users[j : j + 1], placements[j])
        self._alive = alive.clone()
        return self.targets
