"""The plan-aware prediction: where every identity is, flying its plan, from common knowledge.

Why: a re-plan after a failure assigns the new points to the survivors by least travel
from where they are at the re-plan's epoch. Every survivor must compute the same
assignment without a leader, so those positions must come from what all of them know: the
launch line (t = 0, at rest, at the take-off altitude) and the plan's targets since. Each
identity flies its target like `ServiceController` does (`goto_accel` held for tau at the
plan altitude, the twin's point mass, 1 s steps), so this is the exact trajectory of the
plan follower and a close one of any policy that follows the plan; unlike constant-velocity
dead reckoning from an old state, it knows that a UAV in transit brakes at its point.

`PlanMotion` advances a batch of such nominal teams ((B, A, n): agent a's copy of its team
of n identities, in environment b) second by second, and keeps the state at each
signalling instant (`at`), where a re-plan looks it up.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch

from plmarl_sitl.model.vehicle import Limits, goto_accel, step_point_mass

ROUND_M = 0.01  # predicted positions handed to the assignment are rounded like launch_line's


class PlanMotion:
    def __init__(self, limits: Limits, plan_alt_m: float, start_alt_m: float, tau: int,
                 is_instant: Callable[[int], bool]) -> None:
        self.limits, self.plan_alt, self.start_alt, self.tau = limits, plan_alt_m, start_alt_m, tau
        self.is_instant = is_instant
        self.t = 0
        self.state: torch.Tensor | None = None  # (B, A, n, 6) float64 [pos NED, vel NED]
        self.kept: dict[int, torch.Tensor] = {}  # signalling instant -> state then
        self.accel: torch.Tensor | None = None  # the command held since the last decision second

    def start(self, launch: np.ndarray, t: int = 0) -> None:
        """launch (B, A, n, 2): every copy's launch line; at rest at the take-off altitude."""
        xy = torch.from_numpy(np.ascontiguousarray(launch, dtype=np.float64))
        z = torch.full_like(xy[..., :1], -self.start_alt)
        self.state = torch.cat([xy, z, torch.zeros(*xy.shape[:-1], 3, dtype=torch.float64)], -1)
        self.t, self.accel = t, None
        self.kept = {t: self.state.clone()}

    def restart_copy(self, b: int, a: int, launch: np.ndarray) -> None:
        """One copy's launch line changed before it moved (a late state of the first instant)."""
        assert self.state is not None
        for s in [self.state, *self.kept.values()]:
            s[b, a, :, :2] = torch.from_numpy(np.asarray(launch, dtype=np.float64))

    def advance(self, t: int, targets: np.ndarray) -> None:
        """Fly every copy to second t; targets (B, A, n, 2) the points held since the last call."""
        assert self.state is not None
        goal = torch.from_numpy(np.ascontiguousarray(targets, dtype=np.float64))
        goal = torch.where(torch.isnan(goal), self.state[..., :2], goal)  # a failed identity: stays
        goal = torch.cat([goal, torch.full_like(goal[..., :1], -self.plan_alt)], -1)
        lim = self.limits
        while self.t < t:
            if self.t % self.tau == 0 or self.accel is None:
                p, v = self.state[..., :3], self.state[..., 3:]
                self.accel = goto_accel(p, v, goal, lim.max_speed, lim.max_accel, time_const=float(self.tau))
            p, v = step_point_mass(self.state[..., :3], self.state[..., 3:], self.accel, 1.0, lim)
            self.state = torch.cat([p, v], -1)
            self.t += 1
            if self.is_instant(self.t):
                self.kept[self.t] = self.state.clone()

    def replay(self, b: int, a: int, since: int, targets: np.ndarray) -> None:
        """Copy (b, a) re-planned for an epoch `since` in the past: its nominal from then on
        is re-flown to the present with its new targets (n, 2), as if every identity had
        switched at the epoch. So every copy that re-planned for that epoch, whenever it
        learnt of it, predicts the same; the kept instants since are rewritten."""
        assert self.state is not None
        if since >= self.t:
            return
        state = self.at(since)[b, a].clone()
        goal = torch.from_numpy(np.ascontiguousarray(targets, dtype=np.float64))
        goal = torch.where(torch.isnan(goal), state[:, :2], goal)
        goal = torch.cat([goal, torch.full_like(goal[..., :1], -self.plan_alt)], -1)
        lim = self.limits
        accel = None
        for s in range(since, self.t):
            if s % self.tau == 0 or accel is None:
                accel = goto_accel(state[:, :3], state[:, 3:], goal, lim.max_speed, lim.max_accel, time_const=float(self.tau))
            p, v = step_point_mass(state[:, :3], state[:, 3:], accel, 1.0, lim)
            state = torch.cat([p, v], -1)
            if s + 1 in self.kept:
                self.kept[s + 1][b, a] = state
        self.state[b, a] = state

    def at(self, t: int) -> torch.Tensor:
        """(B, A, n, 6) the nominal state at signalling instant t (the nearest kept one
        not after t; the current state if t is later than every kept one)."""
        assert self.state is not None
        if t >= self.t:
            return self.state
        times = [s for s in self.kept if s <= t]
        return self.kept[max(times)] if times else self.kept[min(self.kept)]

    def sources(self, b: int, a: int, t: int, ids: np.ndarray) -> np.ndarray:
        """(len(ids), 2) predicted positions of identities `ids` at instant t in copy (b, a),
        rounded to ROUND_M so every copy's assignment breaks ties alike."""
        xy = self.at(t)[b, a, ids, :2].numpy()
        return np.round(xy / ROUND_M) * ROUND_M


__all__ = ["ROUND_M", "PlanMotion"]
