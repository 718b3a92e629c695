"""One map's greedy on dense lattice windows (model/lattice_greedy.py, issues 24.2, 25.1) gives
the same picks in the same order and the same served users, bit for bit, as the sparse
`ServiceGrid._place_one` of 1da32c9 (kept here only, as the reference): on clustered, uniform
and tie-heavy lattice maps, an empty map and single users, N = 2..100 (the re-plans after
failures place fewer points), forced first picks (the search's starts), 1 and 3 km, 25 / 50 /
100 m cells, areas that are no whole number of cells, a forbidding radius beyond the gains'
window, and teams that run out of allowed candidates; maps float32 cannot hold exactly and
grids off the lattice keep the sparse form."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from plmarl_sitl.bench.infer import lattice_mission
from plmarl_sitl.learning.nn.plan import service_grid
from plmarl_sitl.mission import load_mission
from plmarl_sitl.model.lattice_greedy import OFF
from plmarl_sitl.model.placement import MOVE, LocalSearch, SearchPlacement, _LatticeCover, _rows, components, peaks
from plmarl_sitl.model.service import GRID_M, ServiceGrid, plan_geometry

ROOT = Path(__file__).resolve().parents[2]


def reference_place_one(g: ServiceGrid, w: np.ndarray, gain: np.ndarray, n: int,
                        first: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """ServiceGrid._place_one as of 1da32c9 (the sparse form)."""
    c = len(g.cands)
    nr, ne = g.cand_shape
    r = g.reach
    left = w.copy()
    near = np.zeros((nr, ne), dtype=bool)
    apart = np.ones((nr, ne), dtype=bool)
    score = gain[:c].copy()
    grid_score, grid_gain = score.reshape(nr, ne), gain[:c].reshape(nr, ne)
    ptr, idx = g.cover_ptr, g.cover_idx
    chosen = []
    for step in range(n):
        best = int(score.argmax()) if step or first is None else int(first)
        chosen.append(best)
        pt = idx[ptr[best]:ptr[best + 1]]
        wv = left[pt]
        lit = wv > 0
        pt, wv = pt[lit], wv[lit]
        left[pt] = 0.0
        cover = g.covered_by[pt]
        np.subtract.at(gain, cover.ravel(), np.repeat(wv, cover.shape[1]))
        i, j = divmod(best, ne)
        i0, i1, j0, j1 = max(0, i - r), min(nr, i + r + 1), max(0, j - r), min(ne, j + r + 1)
        st = (slice(i0 - i + r, i1 - i + r), slice(j0 - j + r, j1 - j + r))
        near_w, apart_w = near[i0:i1, j0:j1], apart[i0:i1, j0:j1]
        near_w |= g.near_stencil[st]
        apart_w &= g.apart_stencil[st]
        if step == 0:
            score[:] = -1.0
        grid_score[i0:i1, j0:j1] = np.where(near_w & apart_w, grid_gain[i0:i1, j0:j1], -1.0)
    return g.cands[np.asarray(chosen)][None], ((w - left).sum() / (g.sub * g.sub))[None]


def reference_improve(self: LocalSearch, w: np.ndarray, picks: np.ndarray) -> tuple[np.ndarray, float]:
    """LocalSearch.improve as of 1da32c9 (the sparse cover table). picks (k,) -> improved picks, served.
    Each sweep visits the points in order; a point is evaluated if the screen (`screen`,
    at the sweep's start) found it a better move or a point moved earlier in the sweep lies
    near enough to change its gains (the others' evaluation could not move them: skipping
    them gives the plain sequential sweep's result, at a fraction of its cost)."""
    g = self.grid
    nr, ne = g.cand_shape
    picks = picks.copy()
    cnt = self.counts(picks)
    k = len(picks)
    reach = 2.0 * np.sqrt(g.r2) + 2.0 * MOVE * GRID_M * np.sqrt(2.0)  # cover areas that can overlap
    for _ in range(self.sweeps):
        moved = False
        todo = self.screen(w, picks, cnt)
        for i in range(k):
            if not todo[i]:
                continue
            p = int(picks[i])
            mine = g.cover_idx[g.cover_ptr[p]:g.cover_ptr[p + 1]].astype(np.int64)
            cnt[mine] -= 1  # the plan without point i
            lose = float(w[mine][cnt[mine] == 0].sum())
            ri, rj = divmod(p, ne)
            ci, cj = ri + self.di, rj + self.dj
            inside = (ci >= 0) & (ci < nr) & (cj >= 0) & (cj < ne)
            cand = (ci * ne + cj)[inside]
            owner, pt = _rows(g.cover_ptr, g.cover_idx, cand)
            gains = np.bincount(owner, weights=w[pt] * (cnt[pt] == 0), minlength=len(cand))
            better = gains > lose
            best = -1
            if better.any():
                xy = g.cands[picks]
                others = np.arange(k) != i
                cxy = g.cands[cand]
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
                mine = g.cover_idx[g.cover_ptr[picks[i]]:g.cover_ptr[picks[i] + 1]].astype(np.int64)
                later = np.arange(k) > i
                xy = g.cands[picks]
                todo |= later & (np.sqrt(((xy - old) ** 2).sum(-1)) <= reach)
            cnt[mine] += 1
        if not moved:
            break
    return picks, float(w[cnt > 0].sum())


def maps(g: ServiceGrid, seed: int) -> list[np.ndarray]:
    """Clustered, uniform-random, tie-heavy lattices (every other / every third cell alike),
    an empty map and a single user."""
    rng = np.random.default_rng(seed)
    rows, cols = g.rows, g.cols
    out = [rng.poisson(rng.uniform(0.05, 2.0), rows * cols).astype(np.float64) for _ in range(2)]
    for step, value in ((2, 3.0), (3, 1.0)):
        m = np.zeros((rows, cols))
        m[::step, ::step] = value
        out.append(m.ravel())
    for _ in range(3):
        m = np.zeros((rows, cols))
        for _ in range(int(rng.integers(2, 7))):
            c = rng.uniform(0, [rows - 1, cols - 1])
            pts = np.rint(c + rng.normal(0, rng.uniform(0.7, 3.0), (int(rng.integers(20, 150)), 2)))
            pts = np.clip(pts, 0, [rows - 1, cols - 1]).astype(int)
            np.add.at(m, (pts[:, 0], pts[:, 1]), 1.0)
        out.append(m.ravel())
    out.append(np.zeros(rows * cols))
    one = np.zeros(rows * cols)
    one[int(rng.integers(rows * cols))] = 1.0
    out.append(one)
    return out


def same(g: ServiceGrid, counts: np.ndarray, n: int, first: int | None = None) -> None:
    w, gain = g.sub_weights(counts), g.map_gains(counts)
    if first is None:
        got = g.greedy_place(counts[None], n)
    else:
        got = g._place_one(w, np.append(gain, 0.0), n, first)
    want = reference_place_one(g, w, np.append(gain, 0.0), n, first)
    assert np.array_equal(got[0], want[0]), (n, first)
    assert got[1].dtype == want[1].dtype and np.array_equal(got[1], want[1]), (n, first, got[1], want[1])


def grids() -> list[tuple[str, ServiceGrid]]:
    out = [(p.stem, service_grid(load_mission(p)))
           for p in (ROOT / "missions" / "scale_20.yaml", ROOT / "missions" / "suite" / "failure_2of6_a.yaml")]
    out.append(("bench_3km", ServiceGrid(*plan_geometry(lattice_mission(100, 3000.0)))))
    out += [("cell100_odd_area", ServiceGrid(1030.0, 770.0, 100.0, 100.0, 350.0, 20.0)),
            ("cell25", ServiceGrid(600.0, 500.0, 25.0, 60.0, 200.0, 10.0)),
            ("forbid_beyond_gains", ServiceGrid(800.0, 800.0, 50.0, 30.0, 300.0, 40.0)),
            ("runs_out", ServiceGrid(200.0, 200.0, 50.0, 100.0, 350.0, 60.0))]
    return out


@pytest.mark.parametrize(("name", "grid"), grids(), ids=[n for n, _ in grids()])
def test_the_lattice_greedy_is_the_sparse_reference_bit_for_bit(name: str, grid: ServiceGrid) -> None:
    assert grid.lattice is not None  # every grid here is on the lattice
    if name == "forbid_beyond_gains":
        assert grid.lattice.kill_apart
    for k, counts in enumerate(maps(grid, 17)):
        for n in (2, 5, 13, 20, 41, 100):
            same(grid, counts, n)
        for first in peaks(grid, grid.map_gains(counts), 4, 2.0 * np.sqrt(grid.r2)) or [0]:
            same(grid, counts, 20 if k % 2 else 7, first)


def test_the_search_and_a_failure_re_plan_are_the_reference_bit_for_bit(monkeypatch: pytest.MonkeyPatch) -> None:
    grid = service_grid(load_mission(ROOT / "missions" / "scale_20.yaml"))
    counts = np.stack(maps(grid, 5)[:6])
    new = [SearchPlacement().place(grid, counts, n) for n in (6, 19, 20)] + [grid.place(counts, 37)]
    monkeypatch.setattr(ServiceGrid, "_place_one", reference_place_one)
    old = [SearchPlacement().place(grid, counts, n) for n in (6, 19, 20)] + [grid.place(counts, 37)]
    for (a, sa), (b, sb) in zip(new, old, strict=True):
        assert np.array_equal(a, b) and np.array_equal(sa, sb)


def test_a_team_that_runs_out_of_allowed_candidates_takes_candidate_0_as_the_reference() -> None:
    grid = ServiceGrid(200.0, 200.0, 50.0, 100.0, 350.0, 60.0)
    counts = np.ones(grid.rows * grid.cols)
    pts, _ = grid.greedy_place(counts[None], 30)
    assert (pts[0, -5:] == 0.0).all()  # 30 points 120 m apart do not fit on 200 m x 200 m
    same(grid, counts, 30)


def test_maps_float32_cannot_hold_and_grids_off_the_lattice_keep_the_sparse_form() -> None:
    grid = ServiceGrid(*plan_geometry(lattice_mission(20, 1000.0)))
    big = np.zeros(grid.rows * grid.cols)
    big[[10, 50, 51, 200]] = [OFF, 3.0, 1.0, 7.0]  # whole, but the sums outgrow float32's integers
    frac = maps(grid, 3)[5] * 0.5  # half users: not whole numbers
    for counts in (big, frac):
        assert not grid.lattice.exact32(grid.sub_weights(counts))
        same(grid, counts, 20)
    off = ServiceGrid(900.0, 900.0, 60.0, 100.0, 350.0, 20.0)  # 30 m sub-points: off the 25 m lattice
    assert off.lattice is None
    for counts in maps(off, 4)[:4]:
        same(off, counts, 20)


def test_the_lattice_cover_stencil_is_the_sparse_cover_table() -> None:
    for _, grid in grids():
        lat = grid.lattice
        nr, ne = grid.cand_shape
        index = grid.sub_grid(np.arange(len(grid.subpts)))  # (rows_s, cols_s) sub-point index
        padded = np.full(lat.lat_shape, -1)
        padded[lat.pad:lat.pad + index.shape[0], lat.pad:lat.pad + index.shape[1]] = index
        cover = lat.uncover == 0
        for c in np.random.default_rng(0).choice(nr * ne, min(300, nr * ne), replace=False):
            i, j = divmod(int(c), ne)
            lat_r, *_ = lat.row_windows[i]
            lat_c, *_ = lat.col_windows[j]
            dense = padded[lat_r, lat_c][cover]
            sparse = grid.cover_idx[grid.cover_ptr[c]:grid.cover_ptr[c + 1]]
            assert sorted(dense[dense >= 0].tolist()) == sorted(sparse.tolist())


@pytest.mark.parametrize(("name", "grid"), grids()[:4], ids=[n for n, _ in grids()[:4]])
def test_the_lattice_local_search_is_the_reference_bit_for_bit(name: str, grid: ServiceGrid,
                                                              monkeypatch: pytest.MonkeyPatch) -> None:
    """The search's local improvement on the lattice's windows (`_LatticeCover`) against the
    1da32c9 improve: the same picks and served users, from the greedy's plans and from plans
    with every point moved (many moves), N = 2..20."""
    local = LocalSearch(grid)
    rng = np.random.default_rng(1)
    moved = 0
    for counts in maps(grid, 23):
        w, gain = grid.sub_weights(counts), grid.map_gains(counts)
        assert local.lattice_ok(w)
        for n in (2, 6, 13, 20):
            start = grid.greedy_one(w, gain, n)
            shaken = np.clip(start + rng.integers(-3, 4, n) * grid.cand_shape[1] + rng.integers(-3, 4, n), 0,
                             len(grid.cands) - 1)
            for picks in (start, shaken):
                cnt = local.counts(picks)
                lattice = _LatticeCover(local, w, cnt)
                assert np.array_equal(lattice.screen(local, picks), local.screen(w, picks, cnt))
                assert np.array_equal(lattice.counts(), cnt)
                got, served = local.improve(w, picks)
                want, served_ref = reference_improve(local, w, picks)
                assert np.array_equal(got, want) and served == served_ref, (n, picks)
                moved += int((got != picks).sum())
    assert moved > 0  # the maps do move points


def test_the_lattice_gains_are_the_sparse_gains() -> None:
    for _, grid in grids():
        for counts in maps(grid, 29):
            got = grid.lattice.gains(grid.sub_weights(counts))
            want = grid._gains(counts[None])[0, : len(grid.cands)]
            assert got is not None and got.dtype == np.float64 and np.array_equal(got, want)
            assert want.dtype == np.float64 or not counts.any()  # bincount of no cells: int64 zeros
            assert np.array_equal(grid.map_gains(counts), want)
