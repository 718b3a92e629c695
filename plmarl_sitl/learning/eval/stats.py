"""Statistics for the evaluation: mean with a Student-t 95% confidence interval and the
two-sided Mann-Whitney U test (scipy)."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy import stats


def mean_ci95(x: Sequence[float] | np.ndarray) -> tuple[float, tuple[float, float]]:
    """Mean and its 95% CI from the t distribution (n - 1 dof). One sample: a zero-width CI."""
    a = np.asarray(x, dtype=np.float64)
    if a.size == 0:
        raise ValueError("mean_ci95 of an empty sample")
    mean = float(a.mean())
    if a.size < 2:
        return mean, (mean, mean)
    half = float(stats.t.ppf(0.975, a.size - 1) * a.std(ddof=1) / math.sqrt(a.size))
    return mean, (mean - half, mean + half)


def mann_whitney_p(a: Sequence[float], b: Sequence[float]) -> float:
    """Two-sided Mann-Whitney U p-value (1.0 when both samples are constant and equal)."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if np.ptp(np.concatenate([a, b])) == 0:
        return 1.0
    return float(stats.mannwhitneyu(a, b, alternative="two-sided").pvalue)
