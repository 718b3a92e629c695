"""The search's screen on columns (issue 25.1) gives the same result, bit for bit, as the
session-15 screen (kept here only, as the reference): the same screened points on many maps
(clustered random, uniform and lattice-like tie-heavy, after failures with fewer points), and
the same search picks and served users as the search run with the reference screen. The same
for the local improvement with each candidate's moves kept (session 18) against its loop as of
c88ce62 (also kept here only)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from plmarl_sitl.learning.nn.plan import service_grid
from plmarl_sitl.mission import load_mission
from plmarl_sitl.model.placement import (
    MOVE,
    LocalSearch,
    SearchPlacement,
    _LatticeCover,
    _rows,
    _SparseCover,
    components,
)
from plmarl_sitl.model.service import GRID_M

ROOT = Path(__file__).resolve().parents[2]
MISSIONS = [ROOT / "missions" / "suite" / "failure_2of6_a.yaml", ROOT / "missions" / "scale_20.yaml"]


def reference_screen(self: LocalSearch, w: np.ndarray, picks: np.ndarray, cnt: np.ndarray) -> np.ndarray:
    """LocalSearch.screen as of 8e46671 (row gathers of the (C, 2) and (S, 2) tables)."""
    g = self.grid
    nr, ne = g.cand_shape
    k = len(picks)
    ri, rj = np.divmod(picks, ne)
    ci, cj = ri[:, None] + self.di, rj[:, None] + self.dj
    inside = (ci >= 0) & (ci < nr) & (cj >= 0) & (cj < ne)
    point, move = np.nonzero(inside)
    owner, pt = _rows(g.cover_ptr, g.cover_idx, ci[point, move] * ne + cj[point, move])
    who = point[owner]
    d = g.cands[picks[who]] - g.subpts[pt]
    mine = d[:, 0] ** 2 + d[:, 1] ** 2 <= g.r2
    gains = np.bincount(owner, weights=w[pt] * ((cnt[pt] - mine) == 0), minlength=len(point))
    own, opt = _rows(g.cover_ptr, g.cover_idx, picks)
    lose = np.bincount(own, weights=w[opt] * (cnt[opt] == 1), minlength=k)
    return np.bincount(point[gains > lose[point]], minlength=k) > 0


def reference_improve(self: LocalSearch, w: np.ndarray, picks: np.ndarray) -> tuple[np.ndarray, float]:
    """LocalSearch.improve as of c88ce62 (each visit's moves and the points' positions recomputed)."""
    g = self.grid
    nr, ne = g.cand_shape
    picks = picks.copy()
    k = len(picks)
    cover = _LatticeCover(self, w, self.counts(picks)) if self.lattice_ok(w) else _SparseCover(self, w, self.counts(picks))
    reach = 2.0 * np.sqrt(g.r2) + 2.0 * MOVE * GRID_M * np.sqrt(2.0)
    for _ in range(self.sweeps):
        moved = False
        todo = cover.screen(self, picks)
        for i in range(k):
            if not todo[i]:
                continue
            p = int(picks[i])
            ri, rj = divmod(p, ne)
            ci, cj = ri + self.di, rj + self.dj
            inside = (ci >= 0) & (ci < nr) & (cj >= 0) & (cj < ne)
            cand = (ci * ne + cj)[inside]
            lose, gains = cover.without(p, inside)
            better = gains > lose
            best = -1
            if better.any():
                xy = g.cands[picks]
                others = np.arange(k) != i
                cxy = g.cands[cand]
                d = np.sqrt((cxy[:, None, 0] - xy[None, :, 0]) ** 2 + (cxy[:, None, 1] - xy[None, :, 1]) ** 2)
                ok = better & ((d >= self.apart_m) | ~others).all(-1)
                link = (d <= self.link_m) & others
                mates = np.sqrt(((xy - xy[i]) ** 2).sum(-1)) <= self.link_m
                mates[i] = False
                doubt = ok & ~(link | ~mates).all(-1)
                if doubt.any() and k > 1:
                    lab = components(xy, self.link_m, i)
                    for c in sorted(set(lab[lab >= 0].tolist())):
                        ok &= ~doubt | (link & (lab == c)).any(-1)
                if ok.any():
                    best = int(np.where(ok, gains, -1.0).argmax())
            if best >= 0:
                moved = True
                old = g.cands[p]
                picks[i] = cand[best]
                later = np.arange(k) > i
                xy = g.cands[picks]
                todo |= later & (np.sqrt(((xy - old) ** 2).sum(-1)) <= reach)
            cover.add(int(picks[i]))
        if not moved:
            break
    return picks, float(w[cover.counts() > 0].sum())


def many_maps(grid, seed: int) -> np.ndarray:  # noqa: ANN001 - ServiceGrid
    """Clustered, uniform-random and lattice (every other cell alike: ties everywhere) maps."""
    rng = np.random.default_rng(seed)
    k = grid.rows * grid.cols
    out = [rng.poisson(rng.uniform(0.05, 2.0), k).astype(np.float64) for _ in range(4)]
    lattice = np.zeros((grid.rows, grid.cols))
    lattice[::2, ::2] = 3.0
    out.append(lattice.ravel())
    for _ in range(4):
        m = np.zeros((grid.rows, grid.cols))
        for _ in range(int(rng.integers(2, 6))):
            c = rng.uniform(0, grid.rows - 1, 2)
            pts = np.clip(np.rint(c + rng.normal(0, rng.uniform(0.7, 3.0), (int(rng.integers(20, 120)), 2))), 0,
                          grid.rows - 1)
            np.add.at(m, (pts[:, 0].astype(int), pts[:, 1].astype(int)), 1.0)
        out.append(m.ravel())
    return np.stack(out)


@pytest.mark.parametrize("mission", MISSIONS, ids=lambda p: p.stem)
def test_the_screen_and_the_search_are_the_reference_bit_for_bit(mission: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    grid = service_grid(load_mission(mission))
    counts = many_maps(grid, 7)
    local = LocalSearch(grid)
    screened = 0
    for row in counts:
        w, gain = grid.sub_weights(row), grid.map_gains(row)
        for n in (2, 5, 9, 14, 20):  # fewer points: the re-plans after failures
            picks = grid.greedy_one(w, gain, n)
            cnt = local.counts(picks)
            new = local.screen(w, picks, cnt)
            assert np.array_equal(new, reference_screen(local, w, picks, cnt))
            screened += int(new.sum())
    assert screened > 0  # the maps do give points a better move
    ns = (4, 11, 20)
    new = [SearchPlacement().place(grid, counts, n) for n in ns]
    monkeypatch.setattr(LocalSearch, "screen", reference_screen)
    monkeypatch.setattr(LocalSearch, "lattice_ok", lambda self, w: False)  # the sparse form (session 17: the lattice's)
    old = [SearchPlacement().place(grid, counts, n) for n in ns]
    for (a, sa), (b, sb) in zip(new, old, strict=True):
        assert np.array_equal(a, b) and np.array_equal(sa, sb)


@pytest.mark.parametrize("mission", MISSIONS, ids=lambda p: p.stem)
def test_the_improvement_is_the_reference_bit_for_bit(mission: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """One LocalSearch over every map and team size (its kept moves reused across them), on the
    lattice and the sparse cover, against the loop as of c88ce62."""
    grid = service_grid(load_mission(mission))
    counts = np.concatenate([many_maps(grid, seed) for seed in range(11, 15)])
    ns = (3, 6, 9, 14, 20)
    moved = 0
    for lattice in (True, False):
        if not lattice:
            monkeypatch.setattr(LocalSearch, "lattice_ok", lambda self, w: False)
        local = LocalSearch(grid)
        for row in counts:
            w, gain = grid.sub_weights(row), grid.map_gains(row)
            for n in ns:
                start = grid.greedy_one(w, gain, n)
                new, got = local.improve(w, start)
                old, ref = reference_improve(local, w, start)
                assert np.array_equal(new, old) and got == ref
                moved += int((new != start).sum())
    assert moved > 0  # the maps do move points
