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

from plmarl_sitl.model.vehicle import Limits, goto_accel_np, step_point_mass_np

ROUND_M = 0.01  # predicted positions handed to the assignment are rounded like launch_line's


def _goto_accel(p: np.ndarray, v: np.ndarray, goal: np.ndarray, lim: Limits, tau: int) -> np.ndarray:
    """`goto_accel` held for tau, as `ServiceController` flies its target, in numpy (bit for bit)."""
    return goto_accel_np(p, v, goal, float(lim.max_speed), float(lim.max_accel), time_const=float(tau))


def _step(state: np.ndarray, accel: np.ndarray, lim: Limits) -> np.ndarray:
    """(..., 6) state one second on under accel (..., 3): `step_point_mass`, bit for bit, in
    numpy (`step_point_mass_np`, the fleet's solver too)."""
    shape = state.shape
    flat = state.reshape(-1, 6)
    p, v = step_point_mass_np(flat[:, :3], flat[:, 3:], accel.reshape(-1, 3), 1.0, lim)
    return np.concatenate([p, v], -1).reshape(shape)


class PlanMotion:
    """The nominal states are numpy float64 arrays (torch views of them are handed out by
    `state` and `at`): the team is flown every second by every agent, and per-call overhead,
    not arithmetic, is what a second of it costs (issue 25: 15 % of an agent's busy time in
    torch).

    The seconds are flown when a state is read, not when `advance` is called: `t` is the
    second the team has been advanced to, `flown` the one its states are at. A deployed
    agent advances at every decision (every tau) and reads the states of the signalling
    instants (every T_up), so it flies T_up seconds back to back, not tau seconds at a time
    in a process whose caches went cold since its last decision (issue 25.1). The same
    seconds are flown with the same points, so the states are the same: points held since
    an earlier call are flown up to `t` before new ones are taken, and a call with a failed
    identity's point (NaN: it stays where it is at the call) flies at once."""

    def __init__(self, limits: Limits, plan_alt_m: float, start_alt_m: float, tau: int,
                 is_instant: Callable[[int], bool]) -> None:
        self.limits, self.plan_alt, self.start_alt, self.tau = limits, plan_alt_m, start_alt_m, tau
        self.is_instant = is_instant
        self.t = 0  # advanced to
        self.flown = 0  # `now` is the state at this second (<= t)
        self._now: np.ndarray | None = None  # (B, A, n, 6) float64 [pos NED, vel NED] at second `flown`
        self.kept: dict[int, np.ndarray] = {}  # signalling instant -> state then
        self.accel: np.ndarray | None = None  # the command held since the last decision second
        self.targets: np.ndarray | None = None  # the points of the seconds flown < t <= advanced
        self.goal: np.ndarray | None = None  # the same at the plan altitude

    @property
    def now(self) -> np.ndarray | None:
        """(B, A, n, 6) float64 the nominal state at second `t` (the array itself)."""
        if self._now is not None:
            self._fly(self.t)
        return self._now

    @property
    def state(self) -> torch.Tensor | None:
        """(B, A, n, 6) the nominal state now (a view: valid until the next `advance`)."""
        if self._now is None:
            return None
        self._fly(self.t)
        return torch.from_numpy(self._now)

    def start(self, launch: np.ndarray, t: int = 0) -> None:
        """launch (B, A, n, 2): every copy's launch line; at rest at the take-off altitude."""
        xy = np.ascontiguousarray(launch, dtype=np.float64)
        z = np.full(xy.shape[:-1] + (1,), -self.start_alt)
        self._now = np.concatenate([xy, z, np.zeros(xy.shape[:-1] + (3,))], -1)
        self.t, self.flown, self.accel, self.targets, self.goal = t, t, None, None, None
        self.kept = {t: self._now.copy()}

    def restart_copy(self, b: int, a: int, launch: np.ndarray) -> None:
        """One copy's launch line changed before it moved (a late state of the first instant)."""
        assert self._now is not None
        self._fly(self.t)
        for s in [self._now, *self.kept.values()]:
            s[b, a, :, :2] = np.asarray(launch, dtype=np.float64)

    def _goal(self, targets: np.ndarray, state: np.ndarray) -> np.ndarray:
        """(..., 3) the points targets (..., 2) at the plan altitude; a failed identity (NaN) stays."""
        goal = np.asarray(targets, dtype=np.float64)
        goal = np.where(np.isnan(goal), state[..., :2], goal)
        return np.concatenate([goal, np.full(goal.shape[:-1] + (1,), -self.plan_alt)], -1)

    def advance(self, t: int, targets: np.ndarray) -> None:
        """Advance every copy to second t; targets (B, A, n, 2) the points held since the
        last call (flown when a state is read: see the class)."""
        assert self._now is not None
        if t <= self.t:
            return
        targets = np.asarray(targets, dtype=np.float64)
        if self.flown < self.t and not np.array_equal(targets, self.targets):
            self._fly(self.t)  # the seconds up to now, with the points held until now
        if self.flown == self.t:  # nothing left to fly: these points from here on
            self.targets, self.goal = targets.copy(), self._goal(targets, self._now)
        self.t = t
        if np.isnan(targets).any():
            self._fly(t)  # a failed identity's goal is where it is now: flown now, not later

    def _fly(self, t: int) -> None:
        """Fly the seconds advanced to and not flown yet, up to second t (<= `t`)."""
        assert self._now is not None
        while self.flown < t:
            if self.flown % self.tau == 0 or self.accel is None:
                self.accel = _goto_accel(self._now[..., :3], self._now[..., 3:], self.goal, self.limits, self.tau)
            self._now = _step(self._now, self.accel, self.limits)
            self.flown += 1
            if self.is_instant(self.flown):
                self.kept[self.flown] = self._now.copy()

    def replay(self, b: int, a: int, since: int, targets: np.ndarray) -> None:
        """Copy (b, a) re-planned for an epoch `since` in the past: its nominal from then on
        is re-flown to the present with its new targets (n, 2), as if every identity had
        switched at the epoch. So every copy that re-planned for that epoch, whenever it
        learnt of it, predicts the same; the kept instants since are rewritten."""
        assert self._now is not None
        if since >= self.t:
            return
        self._fly(self.t)
        state = self._at(since)[b, a].copy()
        goal = self._goal(targets, state)
        accel = None
        for s in range(since, self.t):
            if s % self.tau == 0 or accel is None:
                accel = _goto_accel(state[:, :3], state[:, 3:], goal, self.limits, self.tau)
            state = _step(state, accel, self.limits)
            if s + 1 in self.kept:
                self.kept[s + 1][b, a] = state
        self._now[b, a] = state

    def _at(self, t: int) -> np.ndarray:
        assert self._now is not None
        if t >= self.t:
            self._fly(self.t)
            return self._now
        self._fly(t)  # every instant up to t is kept
        times = [s for s in self.kept if s <= t]
        return self.kept[max(times)] if times else self.kept[min(self.kept)]

    def at(self, t: int) -> torch.Tensor:
        """(B, A, n, 6) the nominal state at signalling instant t (the nearest kept one
        not after t; the current state if t is later than every kept one)."""
        return torch.from_numpy(self._at(t))

    def at_array(self, t: int) -> np.ndarray:
        """`at` as the numpy array itself (valid until the next `advance`, `replay` or `restart_copy`)."""
        return self._at(t)

    def sources(self, b: int, a: int, t: int, ids: np.ndarray) -> np.ndarray:
        """(len(ids), 2) predicted positions of identities `ids` at instant t in copy (b, a),
        rounded to ROUND_M so every copy's assignment breaks ties alike."""
        xy = self._at(t)[b, a, ids, :2]
        return np.round(xy / ROUND_M) * ROUND_M


__all__ = ["ROUND_M", "PlanMotion"]
