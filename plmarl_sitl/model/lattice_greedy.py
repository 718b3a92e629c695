"""The team plan's greedy on one map, on dense lattice windows (issues 24.2, 25.1).

Why: an agent's new map at N = 100 over 3 km is 100 greedy picks, and a pick's cost is the
number of numpy calls it makes, not arithmetic (`ServiceGrid._place_one`'s sparse form: a
dozen calls, the `subtract.at` of ~2 700 (candidate, sub-point) pairs the largest). When the
map's sub-points lie on the candidates' lattice shifted by half a step (a cell side that is
a whole number of GRID_M steps: every mission's 50 m and 100 m cells), the cover relation
depends on the offset between a candidate and a sub-point alone: one stencil. Then a pick is
~9 small calls on fixed windows around it:

- the weight it newly serves is the unserved weight on its stencil (a window of the unserved
  weights, which it then zeroes), and the gains it takes from the candidates around it are
  one product of that window with a fixed 0/1 matrix (which candidates share which sub-point
  with the pick);
- one array holds each candidate's score: its gain where allowed (within R_link of a pick,
  2 d_safe from all), gain - OFF where not yet within R_link of one (OFF a power of two far
  above any gain), -inf once within 2 d_safe of one (for good). A pick adds OFF where it
  newly brings candidates within R_link and -inf where it forbids them.

The same picks as the sparse form, bit for bit: gains and weights are whole numbers (user
counts), so every sum is exact in any order, and gain - OFF + OFF is the gain again; the
argmax over the scores sees the same values on allowed candidates and values below -1 on the
others (the sparse form's -1), so the same candidate wins, ties to the lowest index; with no
allowed candidate left both take candidate 0. tests/model/test_lattice_greedy.py compares the
two on many maps.
"""

from __future__ import annotations

import numpy as np

OFF = 2.0**23  # a not-yet-linked candidate's offset: gain - OFF is exact in float32 for gains below it


class LatticeGreedy:
    """The greedy's picks on one map for a grid whose sub-points (rows_s x cols_s, at
    step * (k + 0.5)) sit on its candidates' lattice (nr x ne, at step * i) shifted by half.

    near_stencil, apart_stencil ((2 reach + 1)^2, centred on a pick): the candidates within
    R_link of it and those at least 2 d_safe from it (`ServiceGrid`'s own)."""

    def __init__(self, cand_shape: tuple[int, int], cells: tuple[int, int], sub: int, step: float, r2: float,
                 near_stencil: np.ndarray, apart_stencil: np.ndarray) -> None:
        self.nr, self.ne = cand_shape
        self.sub_shape = sub_shape = (cells[0] * sub, cells[1] * sub)
        # The cover stencil: sub-point (i + dk, j + dl) is covered by candidate (i, j). Both
        # positions are exact multiples of step / 2, so their difference is exact and the
        # squared distance is the float the sparse table's test computes (model/service.py `_Tiles`).
        span = int(np.sqrt(r2) // step) + 2
        dk = np.arange(-span, span + 1)
        dn = step * (dk + 0.5)
        cover = dn[:, None] ** 2 + dn[None, :] ** 2 <= r2  # (dk, dl) offsets; symmetric in sign of (dk + 0.5)
        rows, cols = np.nonzero(cover)
        k0, k1, l0, l1 = dk[rows.min()], dk[rows.max()], dk[cols.min()], dk[cols.max()]
        cover = cover[rows.min():rows.max() + 1, cols.min():cols.max() + 1]  # (hk, hl) from offset (k0, l0)
        hk, hl = cover.shape
        # Candidate (i + a, j + b) shares sub-point (i + dk, j + dl) of the pick's stencil when
        # (dk - a, dl - b) is in the stencil too: a in [k0 - k1, k1 - k0].
        self.ga, self.gb = k1 - k0, l1 - l0
        a = np.arange(-self.ga, self.ga + 1)
        b = np.arange(-self.gb, self.gb + 1)
        ok, ol = np.nonzero(cover)  # stencil entries (row in the window, column)
        share = np.zeros((hk, hl, len(a), len(b)))
        for r, c in zip(ok.tolist(), ol.tolist(), strict=True):
            # the candidate at offset (a, b) covers the pick's stencil entry (r, c) iff its own
            # stencil holds entry (r - a, c - b)
            ri, ci = r - a, c - b
            inside_r, inside_c = (ri >= 0) & (ri < hk), (ci >= 0) & (ci < hl)
            mates = np.zeros((len(a), len(b)), dtype=bool)
            mates[np.ix_(inside_r, inside_c)] = cover[np.ix_(ri[inside_r], ci[inside_c])]
            share[r, c] = mates
        # (stencil window, gain window) 0/1, float32: with whole weights summing below OFF
        # (`exact32`) every product and partial sum is exact, at half the float64 product's cost
        self.share = share.reshape(hk * hl, len(a) * len(b)).astype(np.float32)
        self.uncover = (~cover).astype(np.float32)  # multiplies the window: the stencil's weight served
        self.hk, self.hl = hk, hl
        self.cover_origin = (int(k0), int(l0))  # the stencil's first row and column, as offsets from the candidate
        # The unserved weights, padded so a pick's stencil window never leaves the array
        pad = int(max(abs(k0), abs(k1), abs(l0), abs(l1))) + 1
        self.pad = pad
        self.lat_shape = (max(sub_shape[0], self.nr) + 2 * pad, max(sub_shape[1], self.ne) + 2 * pad)
        # Linking and forbidding: the tight windows of the stencils; a linked score is >= 0, a
        # not yet linked one < -OFF / 2 (and -inf stays -inf whatever is added)
        reach = near_stencil.shape[0] // 2
        self.near_stencil_reach = reach
        self.unlink = np.where(near_stencil, 0.0, 1.0).astype(np.float32)  # times the offsets: 0 where linked
        # Forbidding rides on the gains' product: +inf taken where the pick is nearer than
        # 2 d_safe (inside the gain window when that lies within 2 cover radii, else its own pass)
        far = ~apart_stencil
        ga, gb = self.ga, self.gb
        self.kill_r = self._extent(far, reach) if far.any() else -1
        self.kill_apart = self.kill_r > min(ga, gb)
        self.kill = np.where(far, -np.inf, 0.0).astype(np.float32)
        self.forbid = np.zeros(self.share.shape[1], dtype=np.float32)
        if not self.kill_apart:
            self.forbid[:] = np.where(far[reach - ga:reach + ga + 1, reach - gb:reach + gb + 1], np.inf, 0.0).ravel()
        # Per pick row i (column j): the slices of the lattice window, the gain window (in the
        # candidates' array and in the product's), the link window (in the candidates' array
        # and in its stencil); clipped at the edges, built once
        near_r = self._extent(near_stencil, reach)
        self.row_windows = [self._windows(i, self.nr, pad + int(k0), hk, ga, near_r, reach) for i in range(self.nr)]
        self.col_windows = [self._windows(j, self.ne, pad + int(l0), hl, gb, near_r, reach) for j in range(self.ne)]

        # A map's gains from scratch: each stencil row is one run of columns (a disk), so a
        # candidate's gain is a sum over the rows of run sums, each a difference of one
        # cumulative sum along the rows (whole numbers in float64: exact)
        runs = [np.flatnonzero(row) for row in cover]
        self.row_runs = [(r, int(c[0]), int(c[-1])) for r, c in enumerate(runs) if len(c)] \
            if all(len(c) == 0 or c[-1] - c[0] + 1 == len(c) for c in runs) else None
        self.cum = np.zeros((self.lat_shape[0], self.lat_shape[1] + 1))
        self.off = np.empty(cand_shape, dtype=np.float32)
        self.score = np.empty(self.nr * self.ne, dtype=np.float32)
        self.left = np.zeros(self.lat_shape, dtype=np.float32)
        # the unserved weights' lattice seen cell-major: (cell row, sub row, cell column, sub column)
        self.left_cells = self.left[pad:pad + sub_shape[0], pad:pad + sub_shape[1]].reshape(cells[0], sub, cells[1], sub)
        assert np.shares_memory(self.left_cells, self.left)
        self.cells, self.sub = cells, sub

    @staticmethod
    def _windows(i: int, size: int, lat0: int, lat_len: int, g: int, rn: int, reach: int) -> tuple[slice, ...]:
        def clip(r: int, centre: int) -> tuple[slice, slice]:
            lo, hi = max(0, i - r), min(size, i + r + 1)
            return slice(lo, hi), slice(lo - i + centre, hi - i + centre)

        return (slice(i + lat0, i + lat0 + lat_len), *clip(g, g), *clip(rn, reach))

    @staticmethod
    def _extent(mask: np.ndarray, reach: int) -> int:
        """Half-width of the smallest centred window holding every True of mask."""
        rows, cols = np.nonzero(mask)
        return int(max(np.abs(rows - reach).max(), np.abs(cols - reach).max()))

    @staticmethod
    def exact32(weights: np.ndarray) -> bool:
        """Whole, non-negative weights summing below OFF: float32 holds every gain, sum and
        gain - OFF exactly."""
        return bool(weights.min(initial=0.0) >= 0.0 and weights.sum() < OFF and np.array_equal(weights, np.trunc(weights)))

    def gains(self, weights: np.ndarray) -> np.ndarray | None:
        """(C,) float64 each candidate's gain on the sub-point weights weights (S,) (cell-major,
        `exact32`): `ServiceGrid._gains`'s numbers at a fixed cost (~13 calls on the whole
        lattice), cheaper than its bincount on maps with users in many cells; None for a
        stencil that is no disk."""
        if self.row_runs is None:
            return None
        nr, ne = self.nr, self.ne
        p = self.pad
        k0, l0 = self.cover_origin
        self._spread(weights)
        cum = self.cum
        np.cumsum(self.left, axis=1, dtype=np.float64, out=cum[:, 1:])
        runs: dict[tuple[int, int], np.ndarray] = {}
        out = np.zeros((nr, ne))
        for r, lo, hi in self.row_runs:
            if (lo, hi) not in runs:
                a, b = p + l0 + lo, p + l0 + hi + 1
                runs[lo, hi] = cum[:, b:b + ne] - cum[:, a:a + ne]  # (padded rows, ne) sums of the run
            out += runs[lo, hi][p + k0 + r:p + k0 + r + nr]
        return out.reshape(-1)

    def _spread(self, weights: np.ndarray) -> None:
        """The sub-point weights (S,), cell-major, onto the work lattice `left` (inside its pad)."""
        s = self.sub
        self.left_cells[...] = weights.reshape(self.cells[0], self.cells[1], s, s).transpose(0, 2, 1, 3)

    def place(self, weights: np.ndarray, gain: np.ndarray, n: int, first: int | None = None) -> tuple[list[int], float]:
        """The picks (candidate indices) and the weight they serve, on the sub-point weights
        weights (S,) (cell-major, as `ServiceGrid`'s; `exact32`) and the candidates' gains
        gain (C,), the first pick forced to `first` when given."""
        nr, ne = self.nr, self.ne
        gains = gain[: nr * ne].astype(np.float32).reshape(nr, ne)  # -inf once forbidden
        off, score, left = self.off, self.score, self.left  # this object's work arrays: one map at a time
        off.fill(OFF)  # OFF where not yet linked, else 0
        self._spread(weights)  # unserved weight per sub-point, on the lattice; the pad stays 0
        gw = self.share.shape[1] // (2 * self.ga + 1)
        share, uncover, unlink, forbid, kill_apart = self.share, self.uncover, self.unlink, self.forbid, self.kill_apart
        flat_gains, flat_off = gains.reshape(-1), off.reshape(-1)
        rows, cols = self.row_windows, self.col_windows
        chosen = []
        for step in range(n):
            if step == 0:  # before the first pick every candidate is allowed
                best = int(flat_gains.argmax()) if first is None else int(first)
            else:
                np.subtract(flat_gains, flat_off, out=score)
                best = int(score.argmax())  # ties: lowest candidate index
                if score[best] < 0.0:  # nothing allowed: the sparse form's argmax over all -1
                    best = 0
            chosen.append(best)
            i, j = divmod(best, ne)
            lat_r, gain_r, gst_r, link_r, lst_r = rows[i]
            lat_c, gain_c, gst_c, link_c, lst_c = cols[j]
            win = left[lat_r, lat_c]
            taken = win.ravel() @ share  # (gain window,) the weight each candidate around loses
            taken += forbid
            win *= uncover
            gains[gain_r, gain_c] -= taken.reshape(-1, gw)[gst_r, gst_c]
            off[link_r, link_c] *= unlink[lst_r, lst_c]
            if kill_apart:
                self._forbid(gains, i, j)
        return chosen, float(weights.sum()) - float(left.sum(dtype=np.float64))

    def _forbid(self, gains: np.ndarray, i: int, j: int) -> None:
        """-inf within 2 d_safe of the pick (i, j), when that reaches beyond the gain window."""
        r, reach = self.kill_r, self.near_stencil_reach
        a0, a1, b0, b1 = max(0, i - r), min(self.nr, i + r + 1), max(0, j - r), min(self.ne, j + r + 1)
        gains[a0:a1, b0:b1] += self.kill[a0 - i + reach:a1 - i + reach, b0 - j + reach:b1 - j + reach]


__all__ = ["OFF", "LatticeGreedy"]
