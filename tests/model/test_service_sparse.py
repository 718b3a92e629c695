"""The sparse `ServiceGrid` (issue 24) against the dense tables it replaced: the same points
and the same served users, to the bit, on random maps; and its memory at 3 km."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from plmarl_sitl.model.demand import cell_centres, grid_shape
from plmarl_sitl.model.service import GRID_M, LINK_FRAC, ServiceGrid


class DenseGrid:
    """The dense algorithm as it was before issue 24 (commit cde96d6), kept only as a reference."""

    def __init__(self, area_n: float, area_e: float, cell_m: float, cover_r: float, comm_m: float, safe_m: float) -> None:
        self.sub = max(1, round(cell_m / GRID_M))
        n_axis = np.arange(0.0, area_n + 1e-9, GRID_M)
        e_axis = np.arange(0.0, area_e + 1e-9, GRID_M)
        self.cands = np.stack(np.meshgrid(n_axis, e_axis, indexing="ij"), -1).reshape(-1, 2)
        centres = cell_centres(area_n, area_e, cell_m, torch.float64).numpy()
        offs = (np.arange(self.sub) + 0.5) / self.sub * cell_m - 0.5 * cell_m
        sub = np.stack(np.meshgrid(offs, offs, indexing="ij"), -1).reshape(-1, 2)
        self.subpts = (centres[:, None, :] + sub[None]).reshape(-1, 2)
        d2 = ((self.cands[:, None, :] - self.subpts[None]) ** 2).sum(-1)
        self.r2 = cover_r * cover_r
        self.cover = (d2 <= self.r2).astype(np.float64)
        cd = np.sqrt(((self.cands[:, None, :] - self.cands[None]) ** 2).sum(-1))
        self.link_ok = cd <= LINK_FRAC * comm_m
        self.apart_ok = cd >= 2.0 * safe_m

    def place(self, counts: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
        w = np.repeat(np.asarray(counts, dtype=np.float64), self.sub * self.sub, axis=-1)
        b = w.shape[0]
        unserved = np.ones_like(w)
        allowed = np.ones((b, self.cands.shape[0]), dtype=bool)
        near = np.zeros_like(allowed)
        apart = np.ones_like(allowed)
        chosen = []
        for _ in range(n):
            gain = np.where(allowed, (self.cover @ (w * unserved).T).T, -1.0)
            best = gain.argmax(-1)
            chosen.append(best)
            unserved = unserved * (1.0 - self.cover[best])
            near = near | self.link_ok[best]
            apart = apart & self.apart_ok[best]
            allowed = near & apart
        return self.cands[np.stack(chosen, -1)], (w * (1.0 - unserved)).sum(-1) / (self.sub * self.sub)

    def served(self, counts: np.ndarray, points: np.ndarray) -> np.ndarray:
        w = np.repeat(np.asarray(counts, dtype=np.float64), self.sub * self.sub, axis=-1)
        d2 = ((points[:, :, None, :] - self.subpts[None, None]) ** 2).sum(-1)
        return (w * (d2 <= self.r2).any(1)).sum(-1) / (self.sub * self.sub)


def random_maps(rng: np.random.Generator, k: int, b: int) -> np.ndarray:
    """(b, k) integer user counts: a few dense clusters on a sparse background, or all empty."""
    maps = np.zeros((b, k))
    for row in maps:
        kind = rng.integers(4)
        if kind == 0:
            continue  # an empty map: every gain 0, ties everywhere
        row[rng.choice(k, size=max(1, k // 20), replace=False)] = rng.integers(1, 4, size=max(1, k // 20))
        for _ in range(rng.integers(1, 6)):
            c = rng.integers(k)
            row[max(0, c - 3):c + 3] += rng.integers(5, 60)
        if kind == 3:
            row[:] = rng.integers(0, 3, size=k)  # dense, many equal gains
    return maps


CASES = [  # area_n, area_e, cell_m, cover_r, comm_m, safe_m
    (1000.0, 1000.0, 50.0, 100.0, 350.0, 20.0),  # the paper's
    (600.0, 450.0, 100.0, 100.0, 350.0, 20.0),
    (430.0, 710.0, 50.0, 137.3, 260.0, 11.0),  # neither side a multiple of a cell or of the grid
    (500.0, 300.0, 40.0, 62.5, 180.0, 30.0),
    (500.0, 500.0, 50.0, 100.0, 350.0, 25.0),  # d_safe: candidates exactly 2 d_safe apart (a boundary)
    (700.0, 600.0, 50.0, 80.0, 157.89473684210526, 20.0),  # 0.95 R_comm = 150 m exactly: candidates on the link boundary
    (400.0, 400.0, 50.0, 75.0, 20.0, 15.0),  # links shorter than the spacing: no allowed candidate after the first
]


@pytest.mark.parametrize("case", CASES)
def test_sparse_grid_places_and_serves_exactly_as_the_dense_one(case: tuple) -> None:
    rng = np.random.default_rng(hash(case) % 2**32)
    sparse, dense = ServiceGrid(*case), DenseGrid(*case)
    k = int(np.prod(grid_shape(case[0], case[1], case[2])))
    for n, b in ((1, 1), (4, 3), (9, 1), (9, 5), (25, 1), (25, 2), (40, 1)):  # b = 1: the windowed updates
        maps = random_maps(rng, k, b)
        pts, served = sparse.place(maps, n)
        ref_pts, ref_served = dense.place(maps, n)
        assert np.array_equal(pts, ref_pts), (case, n)
        assert np.array_equal(served, ref_served), (case, n)
        other = ref_pts + rng.normal(0.0, 40.0, ref_pts.shape)  # off-grid points, some outside the area
        assert np.array_equal(sparse.served(maps, other), dense.served(maps, other))
        assert np.array_equal(sparse.served(maps, pts), ref_served)


def test_grid_memory_grows_with_the_area_not_its_square() -> None:
    """At 3 km x 3 km (14,641 candidates, 14,400 sub-points) the dense tables took ~3.5 GB;
    the sparse grid's arrays are a few MB, and a plan for 100 UAVs allocates little more."""
    import tracemalloc

    tracemalloc.start()
    grid = ServiceGrid(3000.0, 3000.0, 50.0, 100.0, 350.0, 20.0)
    built, peak_build = tracemalloc.get_traced_memory()
    tracemalloc.reset_peak()
    counts = np.zeros((1, grid.rows * grid.cols))
    counts[0, ::37] = 60.0
    grid.place(counts, 100)
    _, peak_place = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    held = sum(a.nbytes for a in vars(grid).values() if isinstance(a, np.ndarray))
    assert held < 12e6, held
    assert built < 16e6 and peak_build < 40e6, (built, peak_build)
    assert peak_place - built < 16e6, peak_place - built
