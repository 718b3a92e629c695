"""Least-cost assignment without importing `scipy.optimize`: the same answer as
`scipy.optimize.linear_sum_assignment`, bit for bit.

Why: the agents' forkserver imported scipy.optimize for this one function, ~40 MB of every
agent's RSS (issue 24: agent RSS at N = 100): the package's __init__ imports all of
scipy.optimize (minimize, linprog, sparse, linalg, ...). The function itself is one small
compiled module, `scipy/optimize/_lsap*.so`, which needs only numpy: `linear_sum_assignment`
loads that file alone (~30 KB of RSS), without running the package's __init__.

If that file is missing (another SciPy layout, or no SciPy), `lsa_numpy` is used: a port of SciPy's own algorithm
(scipy/optimize/rectangular_lsap/rectangular_lsap.cpp: the shortest augmenting path method
of Crouse, "On implementing 2D rectangular assignment algorithms", IEEE TAES 2016), with
its scan order, its tie-break (an unassigned column wins a tie) and its float operations in
the same order, so that every exact tie resolves alike and the agents, the twin and the tests
get the same assignment as before (tests/model/test_assignment.py checks against SciPy on
random, integer-tied and rectangular matrices). The inner loop over the columns is one numpy
vector operation per augmenting step: O(n^2) steps' worth of Python for n rows, about 1 ms
at n = 30 and a few ms at n = 100 (SciPy's C: ~0.1 ms), paid only when a plan is assigned.
"""

from __future__ import annotations

import glob
import importlib.machinery
import importlib.util
import os
import sys
from collections.abc import Callable

import numpy as np

_MODULE = "scipy.optimize._lsap"


def _compiled() -> Callable | None:
    """SciPy's compiled `linear_sum_assignment`, loaded from its extension file alone (or the
    module already imported with scipy.optimize); None if there is no such file."""
    if _MODULE in sys.modules:
        return sys.modules[_MODULE].linear_sum_assignment
    try:
        spec = importlib.util.find_spec("scipy")  # finds the package without importing it
    except (ImportError, ValueError):
        return None
    if spec is None or spec.origin is None:
        return None
    files = sorted(glob.glob(os.path.join(os.path.dirname(spec.origin), "optimize", "_lsap.*.so")))
    if not files:
        return None
    try:
        loader = importlib.machinery.ExtensionFileLoader(_MODULE, files[0])
        mod = importlib.util.module_from_spec(importlib.util.spec_from_file_location(_MODULE, files[0], loader=loader))
        loader.exec_module(mod)
        return mod.linear_sum_assignment
    except (ImportError, OSError, AttributeError):
        return None


_scipy_lsa = _compiled()


def linear_sum_assignment(cost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(row indices, column indices) of a least-cost assignment of cost (nr, nc), minimising:
    `scipy.optimize.linear_sum_assignment(cost)`, from SciPy's compiled module when it can be
    loaded alone, else from the numpy port (the same answer)."""
    if _scipy_lsa is not None:
        rows, cols = _scipy_lsa(np.asarray(cost, dtype=np.float64))
        return np.asarray(rows, dtype=np.int64), np.asarray(cols, dtype=np.int64)
    return lsa_numpy(cost)


def lsa_numpy(cost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(row indices, column indices) of a least-cost assignment of cost (nr, nc), minimising,
    as `scipy.optimize.linear_sum_assignment(cost)` returns them (rows ascending)."""
    cost = np.asarray(cost, dtype=np.float64)
    if cost.ndim != 2:
        raise ValueError(f"expected a matrix (2-D array), got a {cost.shape!r} array")
    if not np.isfinite(cost).all():
        raise ValueError("matrix contains invalid numeric entries")
    nr, nc = cost.shape
    if nr == 0 or nc == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    transpose = nc < nr
    if transpose:
        cost = cost.T
        nr, nc = nc, nr
    cost = np.ascontiguousarray(cost)
    u = np.zeros(nr)
    v = np.zeros(nc)
    path = np.full(nc, -1, dtype=np.int64)
    col4row = np.full(nr, -1, dtype=np.int64)
    row4col = np.full(nc, -1, dtype=np.int64)
    for cur in range(nr):
        spc = np.full(nc, np.inf)  # shortest path costs
        sr = np.zeros(nr, dtype=bool)
        sc = np.zeros(nc, dtype=bool)
        remaining = np.arange(nc - 1, -1, -1, dtype=np.int64)  # SciPy scans the columns from the last
        n_rem = nc
        min_val = 0.0
        i = cur
        sink = -1
        while sink == -1:
            sr[i] = True
            rem = remaining[:n_rem]
            r = min_val + cost[i, rem] - u[i] - v[rem]  # the C loop's float operations, in its order
            better = r < spc[rem]
            if better.any():
                upd = rem[better]
                path[upd] = i
                spc[upd] = r[better]
            vals = spc[rem]
            lowest = vals.min()
            # The C scan keeps the first column at the lowest cost, unless an unassigned column at
            # that cost comes later: then the last such one.
            free = np.flatnonzero((vals == lowest) & (row4col[rem] == -1))
            index = int(free[-1]) if len(free) else int(np.argmax(vals == lowest))
            min_val = float(lowest)
            if min_val == np.inf:
                raise ValueError("cost matrix is infeasible")
            j = int(remaining[index])
            if row4col[j] == -1:
                sink = j
            else:
                i = int(row4col[j])
            sc[j] = True
            n_rem -= 1
            remaining[index] = remaining[n_rem]
        u[cur] += min_val
        rows = np.flatnonzero(sr)
        rows = rows[rows != cur]
        u[rows] += min_val - spc[col4row[rows]]
        v[sc] -= min_val - spc[sc]
        j = sink
        while True:
            i = int(path[j])
            row4col[j] = i
            col4row[i], j = j, int(col4row[i])
            if i == cur:
                break
    if transpose:
        order = np.argsort(col4row, kind="stable")
        return col4row[order], order.astype(np.int64)
    return np.arange(nr, dtype=np.int64), col4row


__all__ = ["linear_sum_assignment", "lsa_numpy"]
