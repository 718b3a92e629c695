"""Placements of the team plan's service points other than the plain greedy (issue 24.3).

Why: with perfect knowledge the plan's greedy placement on the 50 m demand map still loses
~0.03 coverage to the clairvoyant reference after a 2-of-6 failure (docs/RESULTS.md, session
14). `SearchPlacement` searches harder on the SAME common knowledge the greedy uses (the
map, the number of points): greedy plans from several first points (the best candidate and
the next peaks 2 coverage radii apart), each improved locally (every point in turn moves to
the best candidate within MOVE steps when that serves more of the map's users, stays 2 d_safe
from the others and keeps the plan connected within R_link), the plan serving the most
users kept (ties: the earlier start). Every quantity is a whole number of sub-point units or
a distance computed with the grid's own float operations, so every agent's copy gets the
same points to the bit; it runs through `ServiceGrid.place` in the twin and the agent alike.
"""

from __future__ import annotations

import numpy as np
import torch

from plmarl_sitl.model.service import GRID_M, ServiceGrid

FIRSTS = 4  # greedy starts: the plain greedy and the next 3 peaks of the map
MOVE = 2  # local improvement: a point moves at most this many candidate steps per move
SWEEPS = 2  # local improvement passes over all points
# Above this many points the search and the learnt placement are the plain greedy: a new plan at N = 100 over 3 km must
# stay within the agent's 50 ms (one start and one sweep there: ~70 ms beside the greedy's
# ~15 ms, docs/RESULTS.md session 15); the suite's teams have at most 20
LARGE_N = 20


def _rows(ptr: np.ndarray, idx: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The entries of several CSR rows: (position in rows, column)."""
    starts, ends = ptr[rows], ptr[rows + 1]
    lens = ends - starts
    owner = np.repeat(np.arange(len(rows)), lens)
    pos = np.arange(int(lens.sum())) - np.repeat(np.cumsum(lens) - lens - starts, lens)
    return owner, idx[pos].astype(np.int64)


def peaks(grid: ServiceGrid, gain: np.ndarray, k: int, apart_m: float) -> list[int]:
    """Up to k candidate indices: the best gain, then the best at least apart_m from all earlier."""
    free = np.ones(len(gain), dtype=bool)
    out: list[int] = []
    for _ in range(k):
        score = np.where(free, gain, -1.0)
        best = int(score.argmax())
        if score[best] <= 0:
            break
        out.append(best)
        free &= np.sqrt((grid.cand_n - grid.cand_n[best]) ** 2 + (grid.cand_e - grid.cand_e[best]) ** 2) >= apart_m
    return out


def components(xy: np.ndarray, link_m: float | np.ndarray, skip: int) -> np.ndarray:
    """(k,) component label (lowest member index) of each point of the link graph of xy (k, 2)
    without point `skip` (its label: -1); link_m a length, or (k, k) one per pair."""
    k = len(xy)
    d = np.sqrt((xy[:, None, 0] - xy[None, :, 0]) ** 2 + (xy[:, None, 1] - xy[None, :, 1]) ** 2)
    rows, cols = np.nonzero(d <= link_m)  # row-major: each point's neighbours together
    ptr = np.searchsorted(rows, np.arange(k + 1)).tolist()
    nb = cols.tolist()
    lab = [-1] * k
    for root in range(k):
        if root == skip or lab[root] >= 0:
            continue
        lab[root] = root
        todo = [root]
        while todo:
            u = todo.pop()
            for j in nb[ptr[u]:ptr[u + 1]]:
                if j != skip and lab[j] < 0:
                    lab[j] = root
                    todo.append(j)
    return np.asarray(lab)


class LocalSearch:
    """Local improvement of one plan on one map (see the module docstring)."""

    def __init__(self, grid: ServiceGrid, sweeps: int = SWEEPS) -> None:
        self.grid, self.sweeps = grid, sweeps
        span = np.arange(-MOVE, MOVE + 1)
        di, dj = np.meshgrid(span, span, indexing="ij")
        keep = (di != 0) | (dj != 0)
        self.di, self.dj = di[keep], dj[keep]  # (M,) the moves, row-major
        self.link_m, self.apart_m = grid.link_m, grid.apart_m
        self.frame: _LatticeFrame | None = None  # built at the first plan on the lattice
        self.moves: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}  # `moves_of`, per candidate visited

    def moves_of(self, p: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Candidate p's moves: which of di, dj stay on the grid (M,) bool, the candidates
        they reach, and those candidates' positions; kept per candidate: the same points
        are visited again by every sweep, start and map (a dozen numpy calls a visit)."""
        held = self.moves.get(p)
        if held is None:
            nr, ne = self.grid.cand_shape
            ri, rj = divmod(p, ne)
            ci, cj = ri + self.di, rj + self.dj
            inside = (ci >= 0) & (ci < nr) & (cj >= 0) & (cj < ne)
            cand = (ci * ne + cj)[inside]
            held = (inside, cand, self.grid.cands[cand])
            for a in held:
                a.setflags(write=False)  # shared by every later visit
            self.moves[p] = held
        return held

    def lattice_frame(self) -> _LatticeFrame:
        if self.frame is None:
            self.frame = _LatticeFrame(self)
        return self.frame

    def counts(self, picks: np.ndarray) -> np.ndarray:
        """(S,) how many picks cover each sub-point."""
        _, pt = _rows(self.grid.cover_ptr, self.grid.cover_idx, picks)
        return np.bincount(pt, minlength=len(self.grid.subpts))

    def screen(self, w: np.ndarray, picks: np.ndarray, cnt: np.ndarray) -> np.ndarray:
        """(k,) bool: the points that have a move serving more than they alone serve now (the
        gains of every point's moves at once, before any of them moves)."""
        g = self.grid
        nr, ne = g.cand_shape
        k = len(picks)
        ri, rj = np.divmod(picks, ne)
        ci, cj = ri[:, None] + self.di, rj[:, None] + self.dj  # (k, M)
        inside = (ci >= 0) & (ci < nr) & (cj >= 0) & (cj < ne)
        point, move = np.nonzero(inside)
        owner, pt = _rows(g.cover_ptr, g.cover_idx, ci[point, move] * ne + cj[point, move])
        at = picks[point[owner]]
        # the cover test's own float operations (ServiceGrid._Tiles), on columns: a gather of
        # (P, 2) rows costs ~5x the two column gathers (issue 25.1)
        dn, de = g.cand_n[at] - g.sub_n[pt], g.cand_e[at] - g.sub_e[pt]
        mine = dn ** 2 + de ** 2 <= g.r2  # the sub-point is also covered by the moving point now
        gains = np.bincount(owner, weights=w[pt] * ((cnt[pt] - mine) == 0), minlength=len(point))
        own, opt = _rows(g.cover_ptr, g.cover_idx, picks)
        lose = np.bincount(own, weights=w[opt] * (cnt[opt] == 1), minlength=k)
        return np.bincount(point[gains > lose[point]], minlength=k) > 0

    def improve(self, w: np.ndarray, picks: np.ndarray) -> tuple[np.ndarray, float]:
        """picks (k,) candidate indices -> improved picks, users served (sub-point units).
        Each sweep visits the points in order; a point is evaluated if the screen (`screen`,
        at the sweep's start) found it a better move or a point moved earlier in the sweep lies
        near enough to change its gains (the others' evaluation could not move them: skipping
        them gives the plain sequential sweep's result, at a fraction of its cost)."""
        g = self.grid
        picks = picks.copy()
        k = len(picks)
        cover = _LatticeCover(self, w, self.counts(picks)) if self.lattice_ok(w) else _SparseCover(self, w, self.counts(picks))
        reach = 2.0 * np.sqrt(g.r2) + 2.0 * MOVE * GRID_M * np.sqrt(2.0)  # cover areas that can overlap
        xy = g.cands[picks]  # the points' positions, kept up to date as they move
        rank = np.arange(k)
        other_than = rank[None, :] != rank[:, None]  # row i: np.arange(k) != i
        after = rank[None, :] > rank[:, None]  # row i: np.arange(k) > i
        for _ in range(self.sweeps):
            moved = False
            todo = cover.screen(self, picks)
            for i in range(k):
                if not todo[i]:
                    continue
                p = int(picks[i])
                inside, cand, cxy = self.moves_of(p)
                lose, gains = cover.without(p, inside)  # the plan without point i, and its moves' gains then
                better = gains > lose
                best = -1
                if better.any():
                    others = other_than[i]
                    d = np.sqrt((cxy[:, None, 0] - xy[None, :, 0]) ** 2 + (cxy[:, None, 1] - xy[None, :, 1]) ** 2)  # (M, k)
                    ok = better & ((d >= self.apart_m) | ~others).all(-1)
                    link = (d <= self.link_m) & others
                    mates = np.sqrt(((xy - xy[i]) ** 2).sum(-1)) <= self.link_m
                    mates[i] = False
                    # a move that keeps every link of the point keeps the plan connected; only
                    # the others need the link graph's components without the point
                    doubt = ok & ~(link | ~mates).all(-1)
                    if doubt.any() and k > 1:
                        lab = components(xy, self.link_m, i)
                        for c in sorted(set(lab[lab >= 0].tolist())):  # not np.unique: it imports numpy.ma (~1 MB, ~10 ms per agent)
                            ok &= ~doubt | (link & (lab == c)).any(-1)
                    if ok.any():
                        best = int(np.where(ok, gains, -1.0).argmax())
                if best >= 0:
                    moved = True
                    old = g.cands[p]
                    picks[i] = cand[best]
                    xy[i] = cxy[best]
                    todo |= after[i] & (np.sqrt(((xy - old) ** 2).sum(-1)) <= reach)
                cover.add(int(picks[i]))
            if not moved:
                break
        return picks, float(w[cover.counts() > 0].sum())

    def lattice_ok(self, w: np.ndarray) -> bool:
        """The moves' gains can be taken on the grid's lattice windows (model/lattice_greedy.py):
        a grid on the lattice and weights float32 sums exactly."""
        return self.grid.lattice is not None and self.grid.lattice.exact32(w)


def kept_local_search(held: LocalSearch | None, grid: ServiceGrid) -> LocalSearch:
    """The LocalSearch held for `grid`, or a new one: its lattice tables are built once per grid."""
    return held if held is not None and held.grid is grid else LocalSearch(grid)


class _SparseCover:
    """How many of the plan's points cover each sub-point (S,), on the sparse cover table."""

    def __init__(self, local: LocalSearch, w: np.ndarray, cnt: np.ndarray) -> None:
        self.grid, self.w, self.cnt = local.grid, w, cnt
        self.moves = (local.di, local.dj)

    def counts(self) -> np.ndarray:
        return self.cnt

    def _mine(self, p: int) -> np.ndarray:
        g = self.grid
        return g.cover_idx[g.cover_ptr[p]:g.cover_ptr[p + 1]].astype(np.int64)

    def without(self, p: int, inside: np.ndarray) -> tuple[float, np.ndarray]:
        """Point p leaves the plan: the weight only it served, and the gains of its moves (the
        `inside` ones of LocalSearch's di, dj), the weight each would newly serve."""
        g, w, cnt = self.grid, self.w, self.cnt
        mine = self._mine(p)
        cnt[mine] -= 1
        lose = float(w[mine][cnt[mine] == 0].sum())
        ne = g.cand_shape[1]
        ri, rj = divmod(p, ne)
        cand = ((ri + self.moves[0]) * ne + rj + self.moves[1])[inside]
        owner, pt = _rows(g.cover_ptr, g.cover_idx, cand)
        return lose, np.bincount(owner, weights=w[pt] * (cnt[pt] == 0), minlength=len(cand))

    def add(self, p: int) -> None:
        self.cnt[self._mine(p)] += 1

    def screen(self, local: LocalSearch, picks: np.ndarray) -> np.ndarray:
        return local.screen(self.w, picks, self.cnt)


class _LatticeCover:
    """`_SparseCover` on the lattice (model/lattice_greedy.py): the counts on the sub-points'
    lattice, padded, and a point's moves' gains (and what it alone serves) one product of the
    unserved weight around it with a fixed 0/1 matrix; whole numbers, exact in float32."""

    def __init__(self, local: LocalSearch, w: np.ndarray, cnt: np.ndarray) -> None:
        self.frame = frame = local.lattice_frame()
        self.w, self.cnt = frame.w, frame.cnt  # the frame's work arrays (one plan at a time): the pad stays 0
        self.w.ravel()[frame.at] = w
        self.cnt.ravel()[frame.at] = cnt

    def counts(self) -> np.ndarray:
        return self.cnt.ravel()[self.frame.at].astype(np.int64)

    def without(self, p: int, inside: np.ndarray) -> tuple[float, np.ndarray]:
        f = self.frame
        w, cnt, own = f.views(p)
        own -= f.stencil
        got = (w * (cnt == 0)).ravel() @ f.share
        return float(got[-1]), got[:-1][inside]

    def add(self, p: int) -> None:
        f = self.frame
        own = f.views(p)[2]
        own += f.stencil

    def screen(self, local: LocalSearch, picks: np.ndarray) -> np.ndarray:
        """`LocalSearch.screen` on the lattice: every point's window at once, one product."""
        f = self.frame
        ri, rj = np.divmod(picks, f.ne)
        at = ((ri + f.k0) * f.shape[1] + rj + f.l0)[:, None] + f.window  # (k, window)
        got = (self.w.ravel()[at] * ((self.cnt.ravel()[at] - f.own) == 0)) @ f.share  # (k, moves + itself)
        ci, cj = ri[:, None] + local.di, rj[:, None] + local.dj
        nr, ne = local.grid.cand_shape
        inside = (ci >= 0) & (ci < nr) & (cj >= 0) & (cj < ne)
        return ((got[:, :-1] > got[:, -1:]) & inside).any(-1)


class _LatticeFrame:
    """The constants of `_LatticeCover` on one grid: the padded lattice (shape), where each
    sub-point sits in it (at), a candidate's window of its moves' covers (its first row and
    column from the candidate: k0, l0; hk x hl), the cover stencil in it, and the 0/1 matrix
    (window, moves and the point itself last)."""

    def __init__(self, local: LocalSearch) -> None:
        g = local.grid
        lat = g.lattice
        self.ne = g.cand_shape[1]
        pad = lat.pad + MOVE
        hk, hl = lat.hk, lat.hl
        self.hk, self.hl = hk + 2 * MOVE, hl + 2 * MOVE
        k0, l0 = lat.cover_origin
        self.k0, self.l0 = pad + k0 - MOVE, pad + l0 - MOVE
        stencil = lat.uncover == 0
        self.stencil = stencil.astype(np.int32)
        moves = list(zip(local.di.tolist(), local.dj.tolist(), strict=True)) + [(0, 0)]
        share = np.zeros((len(moves), self.hk, self.hl), dtype=np.float32)
        for m, (a, b) in enumerate(moves):
            share[m, MOVE + a:MOVE + a + hk, MOVE + b:MOVE + b + hl] = stencil
        self.share = share.reshape(len(moves), -1).T.copy()
        self.own = share[-1].astype(np.int32).ravel()  # the point's own cover in its window
        rows_s, cols_s = g.rows * g.sub, g.cols * g.sub
        self.shape = (lat.lat_shape[0] + 2 * MOVE, lat.lat_shape[1] + 2 * MOVE)
        inner = np.zeros(self.shape, dtype=bool)
        inner[pad:pad + rows_s, pad:pad + cols_s] = True
        self.at = np.flatnonzero(inner)[g.sub_grid(np.arange(len(g.subpts))).ravel().argsort()]
        self.window = (np.arange(self.hk)[:, None] * self.shape[1] + np.arange(self.hl)[None, :]).ravel()
        self.w = np.zeros(self.shape, dtype=np.float32)
        self.cnt = np.zeros(self.shape, dtype=np.int32)
        self.held: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}  # `views`, per candidate visited

    def views(self, p: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Candidate p's window of the work arrays w and cnt, and the part of cnt its own cover
        adds to (views, written in place); kept per candidate, as `LocalSearch.moves_of`: a
        point is visited by every sweep, start and map, and slicing them anew was ~a fifth of a
        visit's cover bookkeeping (issue 25.1). The work arrays are never replaced, so the views stay theirs."""
        held = self.held.get(p)
        if held is None:
            i, j = divmod(p, self.ne)
            rs, cs = slice(i + self.k0, i + self.k0 + self.hk), slice(j + self.l0, j + self.l0 + self.hl)
            cnt = self.cnt[rs, cs]
            held = self.held[p] = (self.w[rs, cs], cnt, cnt[MOVE:self.hk - MOVE, MOVE:self.hl - MOVE])
        return held


class SearchPlacement:
    """Multi-start greedy + local improvement on the map (a `model/service.py::Placer`)."""

    def __init__(self, firsts: int = FIRSTS) -> None:
        self.firsts = firsts
        self.local: LocalSearch | None = None

    def search(self, grid: ServiceGrid, w: np.ndarray, gain: np.ndarray, n: int) -> tuple[np.ndarray, float]:
        """The best plan (n,) candidate indices on sub-point weights w (S,), candidates' gains
        gain (C,), and the weight it serves."""
        self.local = local = kept_local_search(self.local, grid)
        best: tuple[np.ndarray, float] | None = None
        for first in peaks(grid, gain, self.firsts, 2.0 * np.sqrt(grid.r2)) or [0]:
            picks, got = local.improve(w, grid.greedy_one(w, gain, n, first))
            if best is None or got > best[1]:
                best = (picks, got)
        assert best is not None
        return best

    def place(self, grid: ServiceGrid, counts: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
        if n > LARGE_N:
            return grid.greedy_place(counts, n)
        pts, served = [], []
        for row in np.asarray(counts, dtype=np.float64):
            picks, got = self.search(grid, grid.sub_weights(row), grid.map_gains(row), n)
            pts.append(grid.cands[picks])
            served.append(got / (grid.sub * grid.sub))
        return np.stack(pts), np.asarray(served)


TOP = 24  # learned placement: the scorer ranks this many allowed candidates of the largest marginal gain
FEATURES = 7  # per-candidate inputs of the scorer (`PickState.features`)


class PickState:
    """The greedy's state on one map while points are picked one by one (`_place_one`'s
    bookkeeping, with the candidates' features a scorer ranks them by). Integer gains, the
    grid's own distance operations: every copy of the plan computes the same state."""

    def __init__(self, grid: ServiceGrid, counts: np.ndarray, n: int) -> None:
        self.grid, self.n = grid, n
        self.w = grid.sub_weights(counts)
        self.left = self.w.copy()  # weight still unserved per sub-point
        self.total = max(float(self.w.sum()), 1.0)
        c = len(grid.cands)
        self.gain = np.append(grid.map_gains(counts), 0.0)  # (C + 1,): the last a scratch slot (covered_by's padding)
        self.gain0 = self.gain[:c].copy()
        self.g0max = max(float(self.gain0.max(initial=0.0)), 1.0)
        self.near = np.zeros(c, dtype=bool)
        self.apart = np.ones(c, dtype=bool)
        self.picks: list[int] = []

    def score(self) -> np.ndarray:
        """(C,) marginal gain where allowed (within R_link of a pick, 2 d_safe from all), else -1."""
        g = self.gain[: len(self.near)]
        return g.copy() if not self.picks else np.where(self.near & self.apart, g, -1.0)

    def top(self, k: int = TOP) -> np.ndarray:
        """Up to k allowed candidates of the largest marginal gain (> 0), best first (ties: lowest index)."""
        sc = self.score()
        order = np.lexsort((np.arange(len(sc)), -sc))[:k]
        return order[sc[order] > 0]

    def features(self, cands: np.ndarray) -> np.ndarray:
        """(k, FEATURES) float64: marginal gain / the best's, first-map gain / the map's best,
        points left / n, unserved share, distance to the nearest pick / R_link (1 before the
        first), picks within R_link / picks so far, rank / TOP."""
        g = self.grid
        k = len(cands)
        gain = self.gain[cands]
        out = np.empty((k, FEATURES))
        out[:, 0] = gain / max(float(gain.max(initial=0.0)), 1.0)
        out[:, 1] = self.gain0[cands] / self.g0max
        out[:, 2] = (self.n - len(self.picks)) / self.n
        out[:, 3] = float(self.left.sum()) / self.total
        if self.picks:
            p = np.asarray(self.picks)
            d = np.sqrt((g.cand_n[cands, None] - g.cand_n[None, p]) ** 2 + (g.cand_e[cands, None] - g.cand_e[None, p]) ** 2)
            out[:, 4] = d.min(-1) / g.link_m
            out[:, 5] = (d <= g.link_m).sum(-1) / len(self.picks)
        else:
            out[:, 4], out[:, 5] = 1.0, 0.0
        out[:, 6] = np.arange(k) / TOP
        return out

    def pick(self, best: int) -> None:
        g = self.grid
        self.picks.append(int(best))
        pt = g.cover_idx[g.cover_ptr[best]:g.cover_ptr[best + 1]]
        wv = self.left[pt]
        lit = wv > 0
        pt, wv = pt[lit], wv[lit]
        self.left[pt] = 0.0
        cover = g.covered_by[pt]
        np.subtract.at(self.gain, cover.ravel(), np.repeat(wv, cover.shape[1]))
        d = np.sqrt((g.cand_n - g.cand_n[best]) ** 2 + (g.cand_e - g.cand_e[best]) ** 2)
        self.near |= d <= g.link_m
        self.apart &= d >= g.apart_m

    def served(self) -> float:
        """Users served on the map (sub-point units / sub^2)."""
        return float((self.w - self.left).sum()) / (self.grid.sub * self.grid.sub)


class LearnedPlacement:
    """Up to LARGE_N points, the greedy whose every pick is the allowed candidate, among the TOP of the largest
    marginal gain, that a learnt scorer (TorchScript, (k, FEATURES) float64 -> (k,)) ranks
    highest (policies/pl-marl/placement.pt, learning/train/placement.py); with no candidate
    of positive gain left, the greedy's own pick. One thread, float64: the same inputs give
    the same scores in every copy."""

    def __init__(self, scorer: torch.jit.ScriptModule, improve: bool = False) -> None:
        self.scorer = scorer
        self.improve = improve  # then the search's local improvement (`LocalSearch`, up to LARGE_N points)
        self.local: LocalSearch | None = None  # kept per grid, as the search's

    @torch.no_grad()
    def choose(self, state: PickState) -> int:
        top = state.top()
        if len(top) == 0:
            return int(state.score().argmax())
        if len(top) == 1:
            return int(top[0])
        s = self.scorer(torch.from_numpy(state.features(top))).numpy()
        return int(top[int(s.argmax())])

    def place(self, grid: ServiceGrid, counts: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
        if n > LARGE_N:  # the greedy: 100 scored picks over 3 km cost ~110 ms of CPU, beyond the agent's 50 ms
            return grid.greedy_place(counts, n)
        pts, served = [], []
        for row in np.asarray(counts, dtype=np.float64):
            state = PickState(grid, row, n)
            for _ in range(n):
                state.pick(self.choose(state))
            picks, got = np.asarray(state.picks), state.served()
            if self.improve and n <= LARGE_N:
                self.local = kept_local_search(self.local, grid)
                picks, units = self.local.improve(state.w, picks)
                got = units / (grid.sub * grid.sub)
            pts.append(grid.cands[picks])
            served.append(got)
        return np.stack(pts), np.asarray(served)


__all__ = ["FEATURES", "FIRSTS", "TOP", "LearnedPlacement", "PickState", "LocalSearch", "SearchPlacement", "components", "peaks"]
