"""The numpy assignment (model/assignment.py) returns what SciPy's returns, bit for bit,
ties included: the agents dropped scipy.optimize for it (issue 24, agent RSS)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment as scipy_lsa

from plmarl_sitl.model import assignment
from plmarl_sitl.model.assignment import linear_sum_assignment, lsa_numpy
from plmarl_sitl.model.service import assign


def _same(cost: np.ndarray) -> None:
    r0, c0 = scipy_lsa(cost)
    for lsa in (linear_sum_assignment, lsa_numpy):  # the compiled module loaded alone, and the numpy port
        r1, c1 = lsa(cost)
        assert r1.tolist() == r0.tolist() and c1.tolist() == c0.tolist(), (lsa, cost)


@pytest.mark.parametrize("seed", range(40))
def test_random_square_and_rectangular(seed: int) -> None:
    rng = np.random.default_rng(seed)
    for nr, nc in [(1, 1), (3, 3), (7, 7), (20, 20), (5, 9), (9, 5), (40, 40)]:
        _same(rng.random((nr, nc)))


@pytest.mark.parametrize("seed", range(40))
def test_exact_ties(seed: int) -> None:
    """Small integer costs: many optimal assignments; the tie-break must be SciPy's."""
    rng = np.random.default_rng(1000 + seed)
    for nr, nc in [(4, 4), (8, 8), (12, 12), (6, 10), (10, 6), (30, 30)]:
        _same(rng.integers(0, 3, (nr, nc)).astype(float))
    _same(np.zeros((6, 6)))
    _same(np.ones((5, 8)))


def test_the_plan_assignment_on_lattices() -> None:
    """The team plan's case: distances from a launch line to a lattice of points (exact ties
    on symmetric maps), as `service.assign` computes them."""
    for n in (4, 9, 16, 25, 100):
        side = int(np.ceil(np.sqrt(n)))
        pts = np.stack(np.meshgrid(np.arange(side) * 200.0, np.arange(side) * 200.0, indexing="ij"), -1).reshape(-1, 2)[:n]
        line = np.stack([np.full(n, 500.0), 100.0 + 25.0 * np.arange(n)], -1)
        cost = np.sqrt(((line[:, None, :] - pts[None]) ** 2).sum(-1))
        _same(cost)
        r, c = scipy_lsa(cost)
        want = np.empty(n, dtype=np.int64)
        want[r] = c
        assert assign(line, pts).tolist() == want.tolist()


def test_bad_input() -> None:
    for lsa in (linear_sum_assignment, lsa_numpy):
        with pytest.raises(ValueError):
            lsa(np.array([[np.nan, 1.0], [1.0, 0.0]]))
        r, c = lsa(np.zeros((0, 3)))
        assert len(r) == len(c) == 0


def test_the_team_plan_does_not_import_scipy_optimize() -> None:
    """The agent's plan imports SciPy's compiled assignment alone, not the scipy.optimize package (~40 MB RSS)."""
    assert assignment._scipy_lsa is not None  # this SciPy has the file: the fast path is tested above
    code = ("import sys, numpy as np; import plmarl_sitl.model.service as s; "
            "print(s.assign(np.zeros((3, 2)), np.ones((3, 2))).tolist()); "
            "print(sorted(m for m in sys.modules if m.startswith('scipy')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.splitlines()
    assert out == ["[0, 1, 2]", "['scipy.optimize._lsap']"]
