"""Service points: a team plan every agent computes alone from information they all share.

Why: with 50-s-old beliefs an agent cannot tell which cluster its teammates are heading
for, so learnt policies send two UAVs to one cluster and leave another empty (issue 12,
T_up 50). Every agent does receive the same things: the ground network's demand map
(model/demand.py, the same message for all) and, at the first signalling instant (t = 0,
everyone on the launch line), the launch states of its teammates. A deterministic plan
computed from those alone is the same in every agent, without any further message:

1. `ServiceGrid.place`: N service points greedily on the demand map (each on the candidate
   point of a 25 m grid that serves the most still-unserved users, within `link_frac` R_comm
   of a point already placed so the plan is connected, and 2 d_safe apart from them). The
   map's users are spread evenly over sub-points GRID_M apart (4 x 4 per 100 m cell, 2 x 2
   per 50 m cell); the gains are integer sums, so every agent gets the same points whatever
   its batch shape.
2. `launch_line`: the team's launch positions, by identity, fitted as a line through the
   ones the agent heard at t = 0 (a launch is a line of equally spaced UAVs; a large swarm's
   line is longer than R_comm, so not everyone hears everyone).
3. `assign`: the points to identities with the least total travel (Hungarian) from there.
4. At every new map: re-place; the new points replace the old only when they serve more
   users (hysteresis), matched to the old points with the least total shift, so each
   identity keeps the nearest successor of its point (`TeamPlan.on_map`).

5. At a failure (issue 24): the failed set and plan epoch every survivor learns by gossip
   (model/gossip.py) re-place one point per survivor on the map of the epoch and assign
   them from the survivors' plan-aware predicted positions then (model/plan_motion.py), so
   survivors that know the same reach the same plan without a leader (`TeamPlans.replan`).

An agent's target is the point of its own identity. It is an input of the policy (its
offset), computed by this module in the twin's controllers and in the deployed agent.
"""

from __future__ import annotations

import numpy as np
import torch
from scipy.optimize import linear_sum_assignment
from scipy.sparse import csr_matrix

from plmarl_sitl.model.demand import cell_centres, grid_shape
from plmarl_sitl.model.plan_motion import ROUND_M, PlanMotion

GRID_M = 25.0  # candidate service points: the Oracle's grid; also the spacing of a cell's sub-points
LINK_FRAC = 0.95  # points placed within this fraction of R_comm of an earlier one (connected plan)
LAUNCH_ROUND_M = 0.01  # the fitted launch line, rounded: the same in every agent's copy (launch_line)
REPLAN_MARGIN = 1.0  # users: a new plan replaces the old one only when it serves more than this many more


class ServiceGrid:
    """The mission's constants of the plan (area, cells, coverage radius, R_comm, d_safe)."""

    def __init__(self, area_n: float, area_e: float, cell_m: float, cover_r: float, comm_m: float, safe_m: float) -> None:
        self.cell_m = cell_m
        self.sub = max(1, round(cell_m / GRID_M))  # sub-points per cell side
        self.rows, self.cols = grid_shape(area_n, area_e, cell_m)
        n_axis = np.arange(0.0, area_n + 1e-9, GRID_M)
        e_axis = np.arange(0.0, area_e + 1e-9, GRID_M)
        self.cands = np.stack(np.meshgrid(n_axis, e_axis, indexing="ij"), -1).reshape(-1, 2)  # (C, 2)
        centres = cell_centres(area_n, area_e, cell_m, torch.float64).numpy()  # (K, 2)
        offs = (np.arange(self.sub) + 0.5) / self.sub * cell_m - 0.5 * cell_m
        sub = np.stack(np.meshgrid(offs, offs, indexing="ij"), -1).reshape(-1, 2)  # (sub^2, 2)
        self.subpts = (centres[:, None, :] + sub[None]).reshape(-1, 2)  # (K * sub^2, 2), cell-major
        d2 = ((self.cands[:, None, :] - self.subpts[None]) ** 2).sum(-1)
        self.r2 = cover_r * cover_r
        self.cover = (d2 <= self.r2).astype(np.float64)  # (C, S)
        # A candidate covers ~3 % of the sub-points: the greedy's gains as a sparse product are
        # 3-5x cheaper (13.9 -> 3.4 ms per new map at N = 20) and still exact (integer sums).
        self.cover_sparse = csr_matrix(self.cover)
        cd = np.sqrt(((self.cands[:, None, :] - self.cands[None]) ** 2).sum(-1))
        self.link_ok = cd <= LINK_FRAC * comm_m
        self.apart_ok = cd >= 2.0 * safe_m

    def _weights(self, counts: np.ndarray) -> np.ndarray:
        """(B, K) user counts -> (B, S) users per sub-point, in units of 1 / sub^2 user (integers)."""
        return np.repeat(np.asarray(counts, dtype=np.float64), self.sub * self.sub, axis=-1)

    def place(self, counts: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Greedy service points for maps counts (B, K): -> (points (B, n, 2), served (B,) users)."""
        w = self._weights(counts)
        b = w.shape[0]
        unserved = np.ones_like(w)
        allowed = np.ones((b, self.cands.shape[0]), dtype=bool)
        near = np.zeros_like(allowed)
        apart = np.ones_like(allowed)
        chosen = []
        for _ in range(n):
            gain = (self.cover_sparse @ (w * unserved).T).T  # (B, C) exact: integer sums
            gain = np.where(allowed, gain, -1.0)
            best = gain.argmax(-1)  # ties: lowest candidate index
            chosen.append(best)
            unserved = unserved * (1.0 - self.cover[best])
            near = near | self.link_ok[best]
            apart = apart & self.apart_ok[best]
            allowed = near & apart
        idx = np.stack(chosen, -1)
        return self.cands[idx], (w * (1.0 - unserved)).sum(-1) / (self.sub * self.sub)

    def served(self, counts: np.ndarray, points: np.ndarray) -> np.ndarray:
        """(B,) users the points (B, n, 2) serve on maps counts (B, K)."""
        w = self._weights(counts)
        d2 = ((points[:, :, None, :] - self.subpts[None, None]) ** 2).sum(-1)  # (B, n, S)
        hit = (d2 <= self.r2).any(1)
        return (w * hit).sum(-1) / (self.sub * self.sub)


def grid_counts(cells: np.ndarray, grid: ServiceGrid) -> np.ndarray:
    """(K,) counts on the grid's cells from map rows cells (R, 3) [centre north, centre east,
    count] (the nonzero cells a message carries, or the whole map)."""
    r = np.clip(np.floor(cells[:, 0] / grid.cell_m), 0, grid.rows - 1).astype(np.int64)
    c = np.clip(np.floor(cells[:, 1] / grid.cell_m), 0, grid.cols - 1).astype(np.int64)
    out = np.zeros(grid.rows * grid.cols)
    np.add.at(out, r * grid.cols + c, cells[:, 2])
    return out


def launch_line(ids: np.ndarray, pos: np.ndarray, n: int) -> np.ndarray:
    """(n, 2) launch positions of identities 0..n-1 fitted as p = a + b id through the
    heard ones (ids (H,), pos (H, 2), the agent itself included); one heard -> all there."""
    ids = np.asarray(ids, dtype=np.float64)
    pos = np.asarray(pos, dtype=np.float64)
    if len(ids) < 2:
        return np.repeat(pos[:1], n, 0)
    design = np.stack([np.ones_like(ids), ids], -1)
    coef, *_ = np.linalg.lstsq(design, pos, rcond=None)  # (2, 2)
    # Rounded to LAUNCH_ROUND_M: fits through different heard subsets of the same line differ
    # in the last bits, and on a symmetric map (a lattice) the assignment has exact ties that
    # those bits break differently in different agents: two agents on one point, one point
    # empty (measured: 19 of 20 points held at N = 20). Rounded, every copy assigns alike.
    return np.round(np.stack([np.ones(n), np.arange(n, dtype=np.float64)], -1) @ coef / LAUNCH_ROUND_M) * LAUNCH_ROUND_M


def assign(sources: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(n,) point index of each source (n, 2) with the least total distance (Hungarian)."""
    cost = np.sqrt(((sources[:, None, :] - points[None]) ** 2).sum(-1))
    rows, cols = linear_sum_assignment(cost)
    out = np.empty(len(sources), dtype=np.int64)
    out[rows] = cols
    return out


class TeamPlans:
    """Copies of the team plan for B teams x A agents (the twin: A = N; a deployed agent: B = A = 1).
    Everything in a plan is common knowledge (the maps, the launch line, the failed set and
    epoch of `model/gossip.py`, and the plan-aware prediction of `model/plan_motion.py`),
    so the agents of a team compute the same points and slots unless what they heard differs.

    A copy's points are (n, 2) rows, the first n_alive of them used (NaN after): after a
    failure re-plan a copy holds fewer points than identities. slot[j] is identity j's row,
    -1 for an identity the copy knows to have failed."""

    def __init__(self, grid: ServiceGrid, n: int, motion: PlanMotion | None = None) -> None:
        self.grid, self.n = grid, n
        self.motion = motion  # the plan-aware prediction; None: no failure re-plans
        self.points: np.ndarray | None = None  # (B, A, n, 2) each copy's points
        self.slot: np.ndarray | None = None  # (B, A, n) row of each identity, per agent's copy
        self.failed: np.ndarray | None = None  # (B, A, n) bool: the failed set the copy was re-planned for
        self.epoch: np.ndarray | None = None  # (B, A) the epoch of that re-plan (0: none)
        self.maps: list[tuple[int, np.ndarray]] = []  # (second, counts (B, K)) of every map the plan took

    def start(self, launch: np.ndarray, counts: np.ndarray, t: int = 0) -> None:
        """launch (B, A, n, 2) each agent's `launch_line`, counts (B, K) the first map."""
        pts = self.grid.place(counts, self.n)[0]  # (B, n, 2)
        b, a = launch.shape[:2]
        self.points = np.repeat(pts[:, None], a, 1)
        self.slot = np.stack([np.stack([assign(la, p) for la in team]) for team, p in zip(launch, pts, strict=True)])
        self.failed = np.zeros((b, a, self.n), dtype=bool)
        self.epoch = np.zeros((b, a), dtype=np.int64)
        self.maps = [(t, counts)]
        if self.motion is not None:
            self.motion.start(launch, t)

    def _groups(self, b: int) -> list[list[int]]:
        """The copies of team b with identical plans (usually one group: all of them)."""
        groups: dict[bytes, list[int]] = {}
        for a in range(self.slot.shape[1]):
            key = self.slot[b, a].tobytes() + np.nan_to_num(self.points[b, a], nan=-1.0).tobytes()
            groups.setdefault(key, []).append(a)
        return list(groups.values())

    def on_map(self, counts: np.ndarray, t: int | None = None) -> None:
        """A new map (B, K): re-place; a copy keeps its plan unless the new one serves more users."""
        assert self.points is not None and self.slot is not None
        if t is not None:
            self.maps.append((t, counts))
        todo = [(b, g) for b in range(len(counts)) for g in self._groups(b)]
        for k in sorted({int((self.slot[b, g[0]] >= 0).sum()) for b, g in todo}):
            part = [(b, g) for b, g in todo if int((self.slot[b, g[0]] >= 0).sum()) == k]
            rows = np.array([b for b, _ in part])
            new, served = self.grid.place(counts[rows], k)
            old = self.grid.served(counts[rows], np.stack([self.points[b, g[0], :k] for b, g in part]))
            for (b, g), pts, gain, keep in zip(part, new, served, old, strict=True):
                if gain > keep + REPLAN_MARGIN:
                    self._move_to(b, g, pts)

    def _move_to(self, b: int, copies: list[int], new: np.ndarray) -> None:
        """Copies of team b take the points new (k, 2): each identity the successor of its point."""
        k = len(new)
        moved = assign(self.points[b, copies[0], :k], new)  # old row r -> new row moved[r]
        for a in copies:
            live = self.slot[b, a] >= 0
            self.slot[b, a, live] = moved[self.slot[b, a, live]]
            self.points[b, a, :k] = new

    def replan(self, b: int, a: int, failed: np.ndarray, epoch: int, sources: np.ndarray | None = None) -> None:
        """Copy (b, a) learnt the failed set failed (n,) with epoch: re-place one point per
        survivor on the map in force at the epoch and assign them by least travel from the
        survivors' plan-aware predicted positions at the epoch; then the maps taken since.
        The prediction is re-flown from the epoch (`PlanMotion.replay`). `sources` (n, 2)
        replaces the predicted positions (the constant-velocity ablation)."""
        assert self.motion is not None and self.points is not None and self.slot is not None
        alive = np.flatnonzero(~failed)
        counts = [c for s, c in self.maps if s <= epoch] or [self.maps[0][1]]
        pts = self.grid.place(counts[-1][b : b + 1], len(alive))[0][0]
        self.points[b, a] = np.nan
        self.points[b, a, : len(alive)] = pts
        self.slot[b, a] = -1
        src = self.motion.sources(b, a, epoch, alive) if sources is None else np.round(sources[alive] / ROUND_M) * ROUND_M
        self.slot[b, a, alive] = assign(src, pts)
        self.failed[b, a], self.epoch[b, a] = failed, epoch
        for s, later in self.maps:
            if s > epoch:
                new, served = self.grid.place(later[b : b + 1], len(alive))
                if served[0] > self.grid.served(later[b : b + 1], self.points[b, a : a + 1, : len(alive)])[0] + REPLAN_MARGIN:
                    self._move_to(b, [a], new[0])
        self.motion.replay(b, a, epoch, self.all_targets()[b, a])

    def targets(self, idents: np.ndarray) -> np.ndarray:
        """(B, A, 2): agent a's target, the point of its identity idents[a] in its own copy
        (an identity its own copy counts as failed: NaN)."""
        assert self.points is not None and self.slot is not None
        own = np.take_along_axis(self.slot, np.asarray(idents).reshape(1, -1, 1), -1)[..., 0]  # (B, A)
        pts = np.take_along_axis(self.points, np.maximum(own, 0)[..., None, None].repeat(2, -1), 2)[:, :, 0]
        return np.where((own >= 0)[..., None], pts, np.nan)

    def all_targets(self) -> np.ndarray:
        """(B, A, n, 2): every identity's point in every copy (a failed one: NaN)."""
        assert self.points is not None and self.slot is not None
        pts = np.take_along_axis(self.points, np.maximum(self.slot, 0)[..., None].repeat(2, -1), 2)
        return np.where((self.slot >= 0)[..., None], pts, np.nan)


__all__ = ["GRID_M", "LINK_FRAC", "REPLAN_MARGIN", "ServiceGrid", "TeamPlans", "assign", "grid_counts", "launch_line"]
