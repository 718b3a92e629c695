"""The coverage transient after a node failure (Fig. 5a), per episode against the Oracle.

Traces are C(t) per second: column j holds C at t = j + 1 s. A node failing at t_f is
dead from the physics step that ends at t_f on, so C(t_f) is already post-failure.
Definitions (T = episode length, all per episode, then summarised over episodes):

* pre-failure level: mean C over t in [t_f - 20, t_f);
* trough: min C over t in [t_f, T];
* post-failure coverage: mean C over [t_f, T], also as a fraction of the Oracle's mean
  over the same seconds of the same episode;
* the Oracle's post-failure level L: mean of the Oracle's C over the second half of the
  post-failure time, t in [t_f + (T - t_f) / 2, T] (after its own re-planning transient);
* time to plateau: the smallest s >= 0 such that the mean C over the WINDOW_S seconds
  [t_f + s, t_f + s + WINDOW_S) is at least PLATEAU_FRACTION * L; none when no such
  window fits before T ("never"). The issue's target: s <= 30 s.
"""

from __future__ import annotations

import numpy as np

from plmarl_sitl.learning.eval.stats import mean_ci95

PLATEAU_FRACTION = 0.95
WINDOW_S = 10
PRE_S = 20
TARGET_S = 30


def plateau_times(trace: np.ndarray, levels: np.ndarray, fail_s: int) -> np.ndarray:
    """(E,) seconds after fail_s until the WINDOW_S-mean reaches PLATEAU_FRACTION * level (nan: never)."""
    post = trace[:, fail_s - 1 :]  # t = fail_s .. T
    if post.shape[1] < WINDOW_S:
        return np.full(trace.shape[0], np.nan)
    kernel = np.ones(WINDOW_S) / WINDOW_S
    means = np.stack([np.convolve(row, kernel, mode="valid") for row in post])  # [e, s]: mean over [t_f + s, +W)
    hit = means >= PLATEAU_FRACTION * levels[:, None]
    first = hit.argmax(1).astype(np.float64)
    first[~hit.any(1)] = np.nan
    return first


def failure_transient(trace: np.ndarray, oracle_trace: np.ndarray, fail_s: int) -> dict:
    """Summary over episodes of one method's transient (traces (E, T), the same episodes)."""
    horizon = trace.shape[1]
    post = trace[:, fail_s - 1 :]
    oracle_post = oracle_trace[:, fail_s - 1 :]
    half = fail_s + (horizon - fail_s) // 2
    level = oracle_trace[:, half - 1 :].mean(1)
    times = plateau_times(trace, level, fail_s)
    trough, trough_ci = mean_ci95(post.min(1))
    frac, frac_ci = mean_ci95(post.mean(1) / np.maximum(oracle_post.mean(1), 1e-9))
    reached = times[~np.isnan(times)]
    return {
        "failure_at_s": fail_s,
        "pre_failure_mean": float(trace[:, max(fail_s - 1 - PRE_S, 0) : fail_s - 1].mean()),
        "trough_mean": trough,
        "trough_ci95": list(trough_ci),
        "post_failure_mean": float(post.mean()),
        "post_failure_fraction_of_oracle_mean": frac,
        "post_failure_fraction_of_oracle_ci95": list(frac_ci),
        "oracle_post_level_mean": float(level.mean()),
        # Median over all episodes, "never" counted as +inf (None when most never reach it).
        "plateau_s_median": _median_with_never(times),
        "plateau_within_target_share": float(np.mean(times <= TARGET_S)) if times.size else 0.0,
        "plateau_target_s": TARGET_S,
        "plateau_never": int(times.size - reached.size),
    }


def _median_with_never(times: np.ndarray) -> float | None:
    med = float(np.median(np.where(np.isnan(times), np.inf, times)))
    return med if np.isfinite(med) else None
