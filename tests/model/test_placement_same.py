"""The search's screen on columns (issue 25.1) gives the same result, bit for bit, as the
session-15 screen (kept here only, as the reference): the same screened points on many maps
(clustered random, uniform and lattice-like tie-heavy, after failures with fewer points), and
the same search picks and served users as the search run with the reference screen."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from plmarl_sitl.learning.nn.plan import service_grid
from plmarl_sitl.mission import load_mission
from plmarl_sitl.model.placement import LocalSearch, SearchPlacement, _rows

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
