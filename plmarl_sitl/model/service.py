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

from collections.abc import Callable
from typing import Protocol

import numpy as np
import torch

from plmarl_sitl.model.assignment import linear_sum_assignment  # SciPy's answer without importing scipy (agent RSS)
from plmarl_sitl.model.channel import mission_coverage
from plmarl_sitl.model.demand import cell_centres, grid_shape
from plmarl_sitl.model.lattice_greedy import LatticeGreedy
from plmarl_sitl.model.plan_motion import ROUND_M, PlanMotion

GRID_M = 25.0  # candidate service points: the greedy reference's grid; also the spacing of a cell's sub-points
LINK_FRAC = 0.95  # points placed within this fraction of R_comm of an earlier one (connected plan)
LAUNCH_ROUND_M = 0.01  # the fitted launch line, rounded: the same in every agent's copy (launch_line)
# Heard launch positions all within this of the mission's own launch line: the copy takes that
# line (common knowledge) instead of a fit. A fit through the 3 states an agent hears at N = 100
# (SINR with 100 transmitters) extrapolates 1 cm of position quantisation to 0.2-0.3 m at the
# line's far end; copies then broke the lattice's exact assignment ties differently (22 points
# held twice at scale_100's first decision: the SITL-to-twin gap of 0.17-0.21).
LAUNCH_SNAP_M = 0.5
# One map's gains on the lattice above this share of cells with users (bench infer's 3 km maps:
# 1 216 of 3 600 cells, bincount 0.46 ms, lattice ~0.2 ms; 47 cells: 0.06 ms against ~0.2)
LATTICE_GAINS_FRAC = 0.125
REPLAN_MARGIN = 1.0  # users: a new plan replaces the old one only when it serves more than this many more


class Placer(Protocol):
    """A placement other than the greedy (model/placement.py): (points (B, n, 2), served (B,))."""

    def place(self, grid: ServiceGrid, counts: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]: ...


class Repairer(Protocol):
    """A failure re-plan that mends the first plan instead of re-solving it (model/repairs.py):
    the survivors' points (m, 2) in identity order, or None (re-solve)."""

    def __call__(self, grid: ServiceGrid, counts: np.ndarray, first: np.ndarray, failed: np.ndarray,
                 src: np.ndarray) -> np.ndarray | None: ...


class ServiceGrid:
    """The mission's constants of the plan (area, cells, coverage radius, R_comm, d_safe).

    Memory and time grow with the area, not its square (issue 24: dense candidates x
    sub-points and candidates x candidates tables held 1-6 GB per agent at 2-3 km). A
    candidate covers only the ~50 sub-points within the coverage radius, so coverage is kept
    sparse both ways (candidate -> sub-points, sub-point -> candidates; int32 indices, built
    with a tile bucket search: each candidate is tested only against the sub-points of the
    tiles around it). The link and spacing tests are computed for the chosen candidate alone,
    near it (`place`). Every distance is computed with the same float operations as a dense
    table would, so the points are the same to the bit (tests/model/test_service_sparse.py
    checks them against a dense reference)."""

    def __init__(self, area_n: float, area_e: float, cell_m: float, cover_r: float, comm_m: float, safe_m: float,
                 placer: Placer | None = None) -> None:
        # Who places the points: None, this greedy; else another placement on the same tables
        # (model/placement.py, issue 24.3), called in the twin and the agent alike through `place`
        self.placer = placer
        self.cell_m = cell_m
        self.sub = max(1, round(cell_m / GRID_M))  # sub-points per cell side
        self.rows, self.cols = grid_shape(area_n, area_e, cell_m)
        n_axis = np.arange(0.0, area_n + 1e-9, GRID_M)
        e_axis = np.arange(0.0, area_e + 1e-9, GRID_M)
        self.cands = np.stack(np.meshgrid(n_axis, e_axis, indexing="ij"), -1).reshape(-1, 2)  # (C, 2)
        self.cand_shape = (len(n_axis), len(e_axis))  # the candidates' lattice, row-major
        self.cand_n, self.cand_e = (np.ascontiguousarray(a) for a in self.cands.T)  # columns: ~8x faster distances
        centres = cell_centres(area_n, area_e, cell_m, torch.float64).numpy()  # (K, 2)
        offs = (np.arange(self.sub) + 0.5) / self.sub * cell_m - 0.5 * cell_m
        sub = np.stack(np.meshgrid(offs, offs, indexing="ij"), -1).reshape(-1, 2)  # (sub^2, 2)
        self.subpts = (centres[:, None, :] + sub[None]).reshape(-1, 2)  # (K * sub^2, 2), cell-major
        self.sub_n, self.sub_e = (np.ascontiguousarray(a) for a in self.subpts.T)  # columns: gathers ~5x faster
        self.r2 = cover_r * cover_r
        self.link_m = LINK_FRAC * comm_m  # a point within this of an earlier one keeps the plan connected
        self.apart_m = 2.0 * safe_m
        # Candidates are exact multiples of GRID_M, so those more than this many steps from a pick
        # along either axis are farther than R_link and 2 d_safe: a pick changes neither test there.
        self.window = int(max(self.link_m, self.apart_m) // GRID_M) + 1
        self.tiles = _Tiles(self.subpts, max(cover_r, GRID_M))
        # cover: candidate -> the sub-points within the coverage radius (CSR); covered_by: the
        # transpose, padded to one row per sub-point with the extra index C (a scratch gain
        # slot), so the candidates of several sub-points are one fancy index, not a CSR gather
        cand, pt = self._cover_pairs()
        self.cover_ptr, self.cover_idx = _csr(cand, pt, len(self.cands), len(self.subpts) - 1)
        order = np.argsort(pt, kind="stable")
        self.covered_by = _padded(pt[order], cand[order], len(self.subpts), len(self.cands))
        # Per cell, the candidates covering any of its sub-points and how many of them (a
        # map's gains from scratch: a cell's users sit on all its sub-points alike, so a
        # third of the sub-point pairs)
        key, mult = np.unique((pt // (self.sub * self.sub)).astype(np.int64) * (len(self.cands) + 1) + cand,
                              return_counts=True)
        cell, cell_cand = np.divmod(key, len(self.cands) + 1)
        self.cell_cover = _padded(cell, cell_cand, self.rows * self.cols, len(self.cands))
        self.cell_mult = _padded(cell, mult, self.rows * self.cols, 0)
        # One map's picks (`_place_one`) update a window of candidates around each pick: the
        # link and spacing tests reach `window` steps, the gains a pick changes 2 cover radii
        # (the candidates covering a sub-point the pick covers). Candidates are exact multiples
        # of GRID_M, so their distances to a pick depend on the offset alone: one stencil.
        self.reach = max(self.window, int(2.0 * cover_r // GRID_M) + 2)
        offs = np.arange(-self.reach, self.reach + 1) * GRID_M
        dist = np.sqrt(offs[:, None] ** 2 + offs[None, :] ** 2)  # the float ops of place's window distances
        self.near_stencil = dist <= self.link_m
        self.apart_stencil = dist >= self.apart_m
        # Sub-points on the candidates' lattice shifted by half a step (a cell side of whole
        # GRID_M steps: 50 m, 100 m): one map's greedy on dense windows, ~3x cheaper, the same picks
        sub_shape = (self.rows * self.sub, self.cols * self.sub)
        self.lattice = LatticeGreedy(self.cand_shape, (self.rows, self.cols), self.sub, GRID_M, self.r2, self.near_stencil,
                                     self.apart_stencil) \
            if len(self.cover_idx) and self._on_lattice(sub_shape) else None

    def _on_lattice(self, sub_shape: tuple[int, int]) -> bool:
        """Candidate (i, j) at GRID_M (i, j) and sub-point (k, l) of `sub_grid` at GRID_M (k + 1/2, l + 1/2), exactly."""
        nr, ne = self.cand_shape
        on_cands = (np.array_equal(self.cand_n, np.repeat(np.arange(nr) * GRID_M, ne))
                    and np.array_equal(self.cand_e, np.tile(np.arange(ne) * GRID_M, nr)))
        north = (np.arange(sub_shape[0]) + 0.5) * GRID_M
        east = (np.arange(sub_shape[1]) + 0.5) * GRID_M
        return on_cands and (np.array_equal(self.sub_grid(self.sub_n), np.repeat(north[:, None], sub_shape[1], 1))
                             and np.array_equal(self.sub_grid(self.sub_e), np.repeat(east[None, :], sub_shape[0], 0)))

    def sub_grid(self, values: np.ndarray) -> np.ndarray:
        """(S,) per sub-point, cell-major -> (rows * sub, cols * sub) on the sub-points' lattice, north-major."""
        s = self.sub
        return values.reshape(self.rows, self.cols, s, s).transpose(0, 2, 1, 3).reshape(self.rows * s, self.cols * s)

    def _cover_pairs(self) -> tuple[np.ndarray, np.ndarray]:
        """(candidate, sub-point) index pairs within the coverage radius, candidate-major;
        built a block of candidates at a time so the transient stays a few MB."""
        cands, pts = [], []
        for lo in range(0, len(self.cands), 1024):
            c, p = self.tiles.within(self.cands[lo:lo + 1024], self.r2)
            cands.append((c + lo).astype(np.int32))
            pts.append(p.astype(np.int32))
        return np.concatenate(cands), np.concatenate(pts)

    def _weights(self, counts: np.ndarray) -> np.ndarray:
        """(B, K) user counts -> (B, S) users per sub-point, in units of 1 / sub^2 user (integers)."""
        return np.repeat(np.asarray(counts, dtype=np.float64), self.sub * self.sub, axis=-1)

    def place(self, counts: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Greedy service points for maps counts (B, K): -> (points (B, n, 2), served (B,) users).

        Each pick is the allowed candidate with the largest gain (the weight of the unserved
        sub-points it covers); ties go to the lowest candidate index, and a pick with no
        allowed candidate left takes candidate 0 (argmax over all -1). Only what is near a
        pick changes with it, so only that is updated (issue 24: 100 picks on a 3 km map):
        the gains, whole numbers kept exactly, lose the weight of the sub-points the pick
        newly serves at the candidates that cover those; the link and spacing tests change
        only in the window of candidates within R_link or 2 d_safe of the pick. One map (an
        agent) takes `_place_one`; a batch of maps (the twin's small areas) updates them
        whole: one vector operation per pick. With a `placer`, its placement instead."""
        if self.placer is not None:
            return self.placer.place(self, counts, n)
        return self.greedy_place(counts, n)

    def greedy_place(self, counts: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
        """`place` by the greedy, whatever the placer."""
        w = self._weights(counts)
        if w.shape[0] == 1:
            return self._place_one(w[0], self._one_map_gains(counts[0], w[0]), n)
        b, c = w.shape[0], len(self.cands)
        unserved = np.ones(w.shape, dtype=bool)
        gain = self._gains(counts)[:, :c].copy()  # contiguous: subtract.at works on its flat view
        near = np.zeros((b, c), dtype=bool)  # within R_link of a pick
        apart = np.ones((b, c), dtype=bool)  # at least 2 d_safe from every pick
        score = gain.copy()  # gain where allowed, else -1; before the first pick everything is allowed
        chosen = []
        for _ in range(n):
            best = score.argmax(-1)  # ties: lowest candidate index
            chosen.append(best)
            # the sub-points the pick newly serves, and the gains they leave
            team, pt = _gather(self.cover_ptr, self.cover_idx, best)
            fresh = unserved[team, pt]
            team, pt = team[fresh], pt[fresh]
            unserved[team, pt] = False
            lit = w[team, pt] > 0
            team, pt = team[lit], pt[lit]
            owner, cand = self._covering(pt)
            np.subtract.at(gain.reshape(-1), team[owner] * c + cand, w[team, pt][owner])
            dist = np.sqrt((self.cand_n - self.cand_n[best][:, None]) ** 2 + (self.cand_e - self.cand_e[best][:, None]) ** 2)
            near |= dist <= self.link_m
            apart &= dist >= self.apart_m
            score = np.where(near & apart, gain, -1.0)
        idx = np.stack(chosen, -1)
        return self.cands[idx], (w * ~unserved).sum(-1) / (self.sub * self.sub)

    def greedy_one(self, w: np.ndarray, gain: np.ndarray, n: int, first: int | None = None) -> np.ndarray:
        """(n,) candidate indices of the greedy's picks on sub-point weights w (S,) with the
        candidates' gains gain (C,) (`map_gains` / `weight_gains`), its first pick forced to
        candidate `first` when given (a placer's other starts)."""
        pts, _ = self._place_one(w, np.append(gain, 0.0), n, first)
        return self._candidate_index(pts[0])

    def map_gains(self, counts: np.ndarray) -> np.ndarray:
        """(C,) each candidate's gain on one map counts (K,), in sub-point units."""
        counts = np.asarray(counts, dtype=np.float64)
        return self._one_map_gains(counts, self.sub_weights(counts))[: len(self.cands)]

    def _one_map_gains(self, counts: np.ndarray, w: np.ndarray) -> np.ndarray:
        """(C + 1,) `_gains` of one map counts (K,) with weights w (S,): on the lattice when
        users sit in more than LATTICE_GAINS_FRAC of the cells (its fixed cost beats the
        bincount's, which grows with them; the same whole numbers either way)."""
        if (self.lattice is not None and np.count_nonzero(counts) > LATTICE_GAINS_FRAC * len(counts)
                and self.lattice.exact32(w)):
            gain = self.lattice.gains(w)
            if gain is not None:
                return np.append(gain, 0.0)
        return self._gains(counts[None])[0]

    def weight_gains(self, w: np.ndarray) -> np.ndarray:
        """(C,) each candidate's gain on sub-point weights w (S,) (whole numbers: exact)."""
        owner = np.repeat(np.arange(len(self.cands)), np.diff(self.cover_ptr))
        return np.bincount(owner, weights=w[self.cover_idx], minlength=len(self.cands))

    def sub_weights(self, counts: np.ndarray) -> np.ndarray:
        """(S,) users per sub-point of one map counts (K,), in units of 1 / sub^2 user (integers)."""
        return self._weights(np.asarray(counts)[None])[0]

    def _place_one(self, w: np.ndarray, gain: np.ndarray, n: int, first: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """`place` on one map, weights w (S,) and gains gain (C + 1,) (`_gains`): the same
        picks with about a dozen small numpy calls per pick (an agent's new map at N = 100 is
        100 picks; per-call overhead, not arithmetic, is what a pick costs). Every candidate a pick changes (its gain, link or
        spacing test) lies within `reach` lattice steps of it, so the score is rewritten on
        that window only; each candidate's gain loses the same weights in the same order as
        in the batch path."""
        if self.lattice is not None and self.lattice.exact32(w):
            picks, units = self.lattice.place(w, gain, n, first)
            return self.cands[np.asarray(picks)][None], np.array([units / (self.sub * self.sub)])
        c = len(self.cands)
        nr, ne = self.cand_shape
        r = self.reach
        left = w.copy()  # the weight still unserved at each sub-point (w where unserved, else 0)
        near = np.zeros((nr, ne), dtype=bool)
        apart = np.ones((nr, ne), dtype=bool)
        score = gain[:c].copy()  # before the first pick everything is allowed
        grid_score, grid_gain = score.reshape(nr, ne), gain[:c].reshape(nr, ne)
        ptr, idx = self.cover_ptr, self.cover_idx
        chosen = []
        for step in range(n):
            best = int(score.argmax()) if step or first is None else int(first)  # ties: lowest candidate index
            chosen.append(best)
            pt = idx[ptr[best]:ptr[best + 1]]
            wv = left[pt]
            lit = wv > 0  # sub-points with users the pick newly serves
            pt, wv = pt[lit], wv[lit]
            left[pt] = 0.0
            cover = self.covered_by[pt]
            np.subtract.at(gain, cover.ravel(), np.repeat(wv, cover.shape[1]))  # flat: ufunc.at's fast path
            i, j = divmod(best, ne)
            i0, i1, j0, j1 = max(0, i - r), min(nr, i + r + 1), max(0, j - r), min(ne, j + r + 1)
            st = (slice(i0 - i + r, i1 - i + r), slice(j0 - j + r, j1 - j + r))
            near_w, apart_w = near[i0:i1, j0:j1], apart[i0:i1, j0:j1]  # views
            near_w |= self.near_stencil[st]
            apart_w &= self.apart_stencil[st]
            if step == 0:
                score[:] = -1.0  # allowed from now on: within R_link of a pick, so in some pick's window
            grid_score[i0:i1, j0:j1] = np.where(near_w & apart_w, grid_gain[i0:i1, j0:j1], -1.0)
        # w - left is w where served, else 0: the elements of w * ~unserved, summed alike
        return self.cands[np.asarray(chosen)][None], ((w - left).sum() / (self.sub * self.sub))[None]

    def _gains(self, counts: np.ndarray) -> np.ndarray:
        """(B, C + 1) each candidate's gain on maps counts (B, K) (the last column: scratch,
        it takes the padding): the weight of the sub-points it covers, counts x how many
        of a cell's sub-points it covers (whole numbers: exact in any order)."""
        counts = np.asarray(counts, dtype=np.float64)
        b, c = counts.shape[0], len(self.cands) + 1
        rows, cells = np.nonzero(counts)
        cover = self.cell_cover[cells]  # (P, D)
        at = (rows[:, None] * c + cover).ravel() if b > 1 else cover.ravel()
        weights = (counts[rows, cells][:, None] * self.cell_mult[cells]).ravel()
        return np.bincount(at, weights=weights, minlength=b * c).reshape(b, c)

    def _covering(self, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(position in pts, candidate) pairs of the candidates covering each sub-point,
        in sub-point order (covered_by without its padding)."""
        cand = self.covered_by[pts]
        keep = cand < len(self.cands)
        owner = np.broadcast_to(np.arange(len(pts))[:, None], cand.shape)
        return owner[keep], cand[keep]

    def served(self, counts: np.ndarray, points: np.ndarray) -> np.ndarray:
        """(B,) users the points (B, n, 2) serve on maps counts (B, K)."""
        w = self._weights(counts)
        n = points.shape[1]
        owner, pt = self._point_covers(points)
        hit = np.zeros(w.shape, dtype=bool)
        hit[owner // n, pt] = True
        return (w * hit).sum(-1) / (self.sub * self.sub)

    def covered(self, points: np.ndarray) -> np.ndarray:
        """(S,) bool: the sub-points some of the points (m, 2) cover (as `served` counts them)."""
        hit = np.zeros(len(self.subpts), dtype=bool)
        hit[self._point_covers(points)[1]] = True
        return hit

    def _point_covers(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(point, sub-point) pairs of the points (..., 2), flattened, and the sub-points each covers."""
        flat = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        at = self._candidate_index(flat)
        if at is not None:  # points on candidates (a plan's): their cover lists, the same pairs
            return _gather(self.cover_ptr, self.cover_idx, at)
        return self.tiles.within(flat, self.r2)

    def _candidate_index(self, xy: np.ndarray) -> np.ndarray | None:
        """(P,) candidate index of each point (P, 2) if every point is exactly a candidate, else None."""
        ij = np.rint(xy / GRID_M)
        nr, ne = self.cand_shape
        if not (np.isfinite(ij).all() and (ij * GRID_M == xy).all() and (ij >= 0).all()
                and (ij[:, 0] < nr).all() and (ij[:, 1] < ne).all()):
            return None
        return (ij[:, 0] * ne + ij[:, 1]).astype(np.int64)


class _Tiles:
    """Points bucketed on square tiles of side >= the search radius: the points within r of a
    query are among those of the 3 x 3 tiles around it."""

    def __init__(self, pts: np.ndarray, side: float) -> None:
        self.pts, self.side = pts, side
        ij = np.floor(pts / side).astype(np.int64)
        self.shape = (int(ij[:, 0].max()) + 1, int(ij[:, 1].max()) + 1)
        key = ij[:, 0] * self.shape[1] + ij[:, 1]
        self.order = np.argsort(key, kind="stable").astype(np.int32)  # points, tile by tile
        self.start = np.searchsorted(key[self.order], np.arange(self.shape[0] * self.shape[1] + 1))

    def within(self, q: np.ndarray, r2: float) -> tuple[np.ndarray, np.ndarray]:
        """(query index, point index) pairs with |q - p|^2 <= r2 (the same float operations
        as ((q[:, None] - p[None]) ** 2).sum(-1) of a dense table)."""
        ti = np.floor(q / self.side).astype(np.int64)  # (Q, 2)
        step = np.arange(-1, 2)
        tn = ti[:, 0, None, None] + step[None, :, None]  # (Q, 3, 1)
        te = ti[:, 1, None, None] + step[None, None, :]  # (Q, 1, 3)
        tn, te = np.broadcast_arrays(tn, te)
        ok = (tn >= 0) & (tn < self.shape[0]) & (te >= 0) & (te < self.shape[1])
        query = np.broadcast_to(np.arange(len(q))[:, None, None], ok.shape)[ok]
        tile = (tn * self.shape[1] + te)[ok]
        owner, slot = _spans(self.start[tile], self.start[tile + 1])
        query, pt = query[owner], self.order[slot]
        d = q[query] - self.pts[pt]
        d2 = d[:, 0] ** 2 + d[:, 1] ** 2  # the float operations of ((q - p) ** 2).sum(-1)
        keep = d2 <= r2
        return query[keep], pt[keep]


def _index_dtype(largest: int) -> type:
    """The smallest index type holding 0..largest: the tables are held by every agent (its
    RSS), and at 3 km their indices fit in 16 bits."""
    return np.uint16 if largest < 2**16 else np.int32


def _csr(rows: np.ndarray, cols: np.ndarray, n_rows: int, largest: int) -> tuple[np.ndarray, np.ndarray]:
    """Row pointers and column indices (0..largest) of (row, col) pairs already grouped by row."""
    ptr = np.zeros(n_rows + 1, dtype=np.int64)
    np.cumsum(np.bincount(rows, minlength=n_rows), out=ptr[1:])
    return ptr, cols.astype(_index_dtype(largest))


def _padded(rows: np.ndarray, cols: np.ndarray, n_rows: int, pad: int) -> np.ndarray:
    """(n_rows, longest row) column indices of (row, col) pairs already grouped by row, each
    row's in order, filled up with `pad`."""
    counts = np.bincount(rows, minlength=n_rows)
    out = np.full((n_rows, int(counts.max(initial=0))), pad, dtype=_index_dtype(max(pad, int(cols.max(initial=0)))))
    starts = np.cumsum(counts) - counts
    out[rows, np.arange(len(rows)) - np.repeat(starts, counts)] = cols
    return out


def _spans(starts: np.ndarray, ends: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All positions of several index ranges [starts, ends) at once: (range number, position)."""
    lens = ends - starts
    owner = np.repeat(np.arange(len(starts)), lens)
    return owner, np.arange(int(lens.sum())) - np.repeat(np.cumsum(lens) - lens - starts, lens)


def _gather(ptr: np.ndarray, idx: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The entries of several CSR rows at once: (position in `rows`, column index) pairs."""
    owner, pos = _spans(ptr[rows], ptr[rows + 1])
    return owner, idx[pos]


def grid_counts(cells: np.ndarray, grid: ServiceGrid) -> np.ndarray:
    """(K,) counts on the grid's cells from map rows cells (R, 3) [centre north, centre east,
    count] (the nonzero cells a message carries, or the whole map)."""
    r = np.clip(np.floor(cells[:, 0] / grid.cell_m), 0, grid.rows - 1).astype(np.int64)
    c = np.clip(np.floor(cells[:, 1] / grid.cell_m), 0, grid.cols - 1).astype(np.int64)
    out = np.zeros(grid.rows * grid.cols)
    np.add.at(out, r * grid.cols + c, cells[:, 2])
    return out


def plan_geometry(mission) -> tuple[float, float, float, float, float, float]:  # noqa: ANN001 - Mission
    """The constants a plan of the mission is laid on: area north, east, demand cell, coverage
    radius, R_comm, d_safe (the team plan's `ServiceGrid` and the neighbourhood plan's `LocalPlan`)."""
    _, cover_r = mission_coverage(mission)
    return (float(mission.area.north_m), float(mission.area.east_m), float(mission.demand.cell_m), float(cover_r),
            float(mission.radii.comm_m), float(mission.radii.safe_m))


def mission_launch_xy(mission) -> np.ndarray:  # noqa: ANN001 - Mission
    """(n, 2) the mission's launch line (north, east), as `twin.env.launch_positions` places it."""
    la = mission.launch
    offs = (np.arange(mission.n_uavs, dtype=np.float64) - (mission.n_uavs - 1) / 2) * la.spacing_m
    d_north, d_east = la.direction()
    return np.stack([la.north_m + offs * d_north, la.east_m + offs * d_east], -1)


def launch_line(ids: np.ndarray, pos: np.ndarray, n: int, nominal: np.ndarray | None = None) -> np.ndarray:
    """(n, 2) launch positions of identities 0..n-1 fitted as p = a + b id through the
    heard ones (ids (H,), pos (H, 2), the agent itself included); one heard -> all there.
    With `nominal` (n, 2), the mission's line: that line if every heard position lies within
    LAUNCH_SNAP_M of its identity's place on it (every copy then has it to the bit)."""
    if nominal is not None and np.abs(np.asarray(pos, dtype=np.float64) - nominal[np.asarray(ids, dtype=np.int64)]).max() <= LAUNCH_SNAP_M:
        return np.round(nominal / LAUNCH_ROUND_M) * LAUNCH_ROUND_M
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

    def __init__(self, grid: ServiceGrid, n: int, motion: PlanMotion | None = None,
                 repairer: Repairer | None = None) -> None:
        self.grid, self.n = grid, n
        self.motion = motion  # the plan-aware prediction; None: no failure re-plans
        # how a failure re-plan is made: None, the whole plan re-solved for the survivors; else
        # the first plan mended (`failure_replan: local`, model/repairs.py), re-solved only
        # where the repairer gives up
        self.repairer = repairer
        self.first: tuple[int, np.ndarray, np.ndarray] | None = None  # (second, points (B, n, 2), slot (B, A, n))
        self.points: np.ndarray | None = None  # (B, A, n, 2) each copy's points
        self.slot: np.ndarray | None = None  # (B, A, n) row of each identity, per agent's copy
        self.failed: np.ndarray | None = None  # (B, A, n) bool: the failed set the copy was re-planned for
        self.epoch: np.ndarray | None = None  # (B, A) the epoch of that re-plan (0: none)
        self.maps: list[tuple[int, np.ndarray]] = []  # (second, counts (B, K)) of every map the plan took
        self.since: np.ndarray | None = None  # (B, A, n) the instant each failed identity was declared at (0: alive)
        # (b, a) -> the copy's re-plan steps (failed set, epoch), and its plan before each of
        # them (failed, epoch, since, points, slot, second saved, the step's epoch), oldest first
        self.steps: dict[tuple[int, int], list[tuple[np.ndarray, int]]] = {}
        self.before: dict[tuple[int, int], list[tuple[np.ndarray, int, np.ndarray, np.ndarray, np.ndarray, int, int]]] = {}

    def start(self, launch: np.ndarray, counts: np.ndarray, t: int = 0) -> None:
        """launch (B, A, n, 2) each agent's `launch_line`, counts (B, K) the first map."""
        pts = self.grid.place(counts, self.n)[0]  # (B, n, 2)
        b, a = launch.shape[:2]
        self.points = np.repeat(pts[:, None], a, 1)
        self.slot = np.stack([np.stack([assign(la, p) for la in team]) for team, p in zip(launch, pts, strict=True)])
        self.failed = np.zeros((b, a, self.n), dtype=bool)
        self.epoch = np.zeros((b, a), dtype=np.int64)
        self.maps = [(t, counts)]
        self.since = np.zeros((b, a, self.n), dtype=np.int64)
        self.steps, self.before = {}, {}
        self.first = (t, pts.copy(), self.slot.copy())
        self._first_cache: dict[tuple[int, int, int], tuple[np.ndarray, np.ndarray]] = {}  # `_first_plan_at`'s
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

    def settle(self, b: int, a: int, failed: np.ndarray, since: np.ndarray,
               sources_at: Callable[[int], np.ndarray] | None = None) -> bool:
        """Copy (b, a) now knows the identities failed (n,) declared at instants since (n,):
        its plan becomes the one re-planned at each of those instants in order (`replan`
        for the identities declared by then), whatever order it learnt them in, so copies
        that know the same hold the same plan. Steps it already made are kept; a step that
        no longer holds (an identity taken back at a newer incarnation, model/gossip.py, or
        a declaration learnt to be earlier) is undone by rolling the copy back to its plan
        before that step. `sources_at(epoch)` (n, 2) replaces the predicted positions (the
        constant-velocity ablation). True if the plan changed."""
        at = sorted({int(x) for x in since[failed]})
        want = [(failed & (since <= s), s) for s in at]
        have = self.steps.setdefault((b, a), [])
        k = 0
        while k < min(len(want), len(have)) and have[k][1] == want[k][1] and np.array_equal(have[k][0], want[k][0]):
            k += 1
        if k == len(want) == len(have):
            return False
        if k < len(have):
            self._roll_back(b, a, k)
        for f, s in want[k:]:
            self.replan(b, a, f.copy(), s, None if sources_at is None else sources_at(s))
        self.since[b, a] = np.where(failed, since, 0)
        return True

    def replan(self, b: int, a: int, failed: np.ndarray, epoch: int, sources: np.ndarray | None = None) -> None:
        """One re-plan step of copy (b, a): the failed set failed (n,) at epoch: the first plan
        mended by the `repairer` (survivors keep identity order), or, without one or where it
        gives up, one point per survivor re-placed on the map in force at the epoch and assigned
        by least travel from the survivors' plan-aware predicted positions at the epoch; then
        the maps taken since. The prediction is re-flown from the epoch (`PlanMotion.replay`). `sources`
        (n, 2) replaces the predicted positions (the constant-velocity ablation)."""
        assert self.motion is not None and self.points is not None and self.slot is not None
        self.before.setdefault((b, a), []).append((self.failed[b, a].copy(), int(self.epoch[b, a]), self.since[b, a].copy(),
                                                   self.points[b, a].copy(), self.slot[b, a].copy(), self.motion.t, int(epoch)))
        self.steps.setdefault((b, a), []).append((failed.copy(), int(epoch)))
        self.since[b, a] = np.where(failed, np.where(self.since[b, a] > 0, self.since[b, a], epoch), 0)
        alive = np.flatnonzero(~failed)
        if alive.size == 0:  # only false declarations get here (the copy's own agent is alive): keep the plan
            self.failed[b, a], self.epoch[b, a] = failed, epoch
            return
        counts = [c for s, c in self.maps if s <= epoch] or [self.maps[0][1]]
        everyone = np.arange(self.n)
        src = self.motion.sources(b, a, epoch, everyone) if sources is None else np.round(sources / ROUND_M) * ROUND_M
        pts = None
        if self.repairer is not None:
            pts = self.repairer(self.grid, counts[-1][b], self._first_plan_at(b, a, epoch), failed, src)
            own = np.arange(len(alive))  # a repair keeps identity order
        if pts is None:
            pts = self.grid.place(counts[-1][b : b + 1], len(alive))[0][0]
            own = assign(src[alive], pts)
        self.points[b, a] = np.nan
        self.points[b, a, : len(alive)] = pts
        self.slot[b, a] = -1
        self.slot[b, a, alive] = own
        self.failed[b, a], self.epoch[b, a] = failed, epoch
        self._follow_maps(b, a, epoch)
        self.motion.replay(b, a, epoch, self.all_targets()[b, a])

    def _follow_maps(self, b: int, a: int, after: int) -> None:
        """Copy (b, a) takes the maps of seconds after `after`, as `on_map` would have."""
        k = int((self.slot[b, a] >= 0).sum())
        for s, later in self.maps:
            if s > after:
                new = self._replacing(later[b], self.points[b, a, :k])
                if new is not None:
                    self._move_to(b, [a], new)

    def _replacing(self, counts: np.ndarray, points: np.ndarray) -> np.ndarray | None:
        """`on_map`'s rule for one copy: the new plan (k, 2) of the map counts (K,) if it serves
        more than REPLAN_MARGIN users more than the points (k, 2) held, else None."""
        new, served = self.grid.place(counts[None], len(points))
        return new[0] if served[0] > self.grid.served(counts[None], points[None])[0] + REPLAN_MARGIN else None

    def _first_plan_at(self, b: int, a: int, epoch: int) -> np.ndarray:
        """(n, 2) identity j's point in copy (b, a)'s first plan as the maps up to `epoch` moved it
        (`on_map`'s rule): what a copy that never learnt of a failure flies. Common knowledge."""
        assert self.first is not None
        t0 = self.first[0]
        taken = [(s, later) for s, later in self.maps if t0 < s <= epoch]
        # The first plan's points and where each of its rows went depend on the team and the
        # maps taken by the epoch only, not on the copy: computed once for all copies (each
        # `grid.place` is a whole placement), again only if a late map of before the epoch came.
        key = (b, epoch, len(taken))
        if key not in self._first_cache:
            points, row = self.first[1][b].copy(), np.arange(self.n)
            for _, later in taken:
                new = self._replacing(later[b], points)
                if new is not None:  # each identity the successor of its point, as `_move_to`
                    row = assign(points, new)[row]
                    points = new
            self._first_cache[key] = (points, row)
        points, row = self._first_cache[key]
        return points[row[self.first[2][b, a]]]

    def _roll_back(self, b: int, a: int, k: int) -> None:
        """Copy (b, a) returns to its plan before its re-plan step k, with the maps taken since
        it was left, and its prediction re-flown from that step's epoch."""
        assert self.motion is not None and self.points is not None and self.slot is not None
        stack, steps = self.before[(b, a)], self.steps[(b, a)]
        was_failed, was_epoch, was_since, points, slot, saved_t, left = stack[k]
        del stack[k:], steps[k:]
        self.failed[b, a], self.epoch[b, a], self.since[b, a] = was_failed, was_epoch, was_since
        self.points[b, a], self.slot[b, a] = points, slot
        self._follow_maps(b, a, saved_t)
        self.motion.replay(b, a, left, self.all_targets()[b, a])

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


__all__ = ["GRID_M", "LAUNCH_SNAP_M", "LINK_FRAC", "REPLAN_MARGIN", "Repairer", "ServiceGrid", "TeamPlans", "assign", "grid_counts", "launch_line",
           "mission_launch_xy"]
