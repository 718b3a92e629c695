"""Statistics for the evaluation: mean with a Student-t 95% confidence interval, the two-sided
Mann-Whitney U test, and the paired Wilcoxon signed-rank test (scipy).

Why both tests: the suite flies every method on the same episodes (same twin seeds, so the same
users, layouts and failures). Mann-Whitney U ignores that pairing and compares two pooled samples,
so a family whose missions differ by far more than the methods do (moving crowds: 0.55 of
coverage between its missions) hides a difference that every episode shows. The signed-rank test
on the per-episode differences is the test of that paired design. Both are reported; neither
replaces the other."""

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


def paired_wilcoxon_p(a: Sequence[float], b: Sequence[float]) -> float:
    """Two-sided Wilcoxon signed-rank p-value of the per-episode differences a - b (the same
    episodes in the same order). Zero differences are dropped (Wilcoxon's own rule); 1.0 when
    none is left."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if a.shape != b.shape:
        raise ValueError(f"paired samples differ in length: {a.shape} and {b.shape}")
    d = a - b
    if not np.any(d != 0):
        return 1.0
    return float(stats.wilcoxon(d, alternative="two-sided").pvalue)


def wins_losses(a: Sequence[float], b: Sequence[float]) -> tuple[int, int]:
    """Episodes where a is above b, and below it (ties count in neither)."""
    d = np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64)
    return int((d > 0).sum()), int((d < 0).sum())


def compare(a: Sequence[float], b: Sequence[float]) -> dict:
    """Method a against method b on the same episodes: {p: Mann-Whitney U, p_paired: Wilcoxon
    signed-rank, wins, losses} (see the module's docstring for why both)."""
    wins, losses = wins_losses(a, b)
    return {"p": mann_whitney_p(a, b), "p_paired": paired_wilcoxon_p(a, b), "wins": wins, "losses": losses}
