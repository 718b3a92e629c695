"""The summary of a recorded run (summary.json), computed from metrics.jsonl rows.

A row is one sim second: {"t", "coverage", "lambda2", "messages", "uavs": [{"id",
"alive", "pos_ned", "vel_ned", "aoi_max"}, ...]}. For each node failure at t_f:
* trough: the lowest coverage from t_f on;
* plateau: the mean coverage over the last `plateau_s` seconds of the run (or up to the
  next failure);
* restabilize_s: seconds from t_f until coverage enters the band plateau +- `band` and
  stays in it (None if it never does).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

PLATEAU_S = 30.0
BAND = 0.02


def failure_recovery(
    t: np.ndarray, coverage: np.ndarray, t_fail: float, t_end: float | None = None, *, plateau_s: float = PLATEAU_S, band: float = BAND
) -> dict:
    """Trough, plateau and re-stabilisation time after a failure at `t_fail`."""
    t_end = float(t[-1]) if t_end is None else t_end
    after = (t >= t_fail) & (t <= t_end)
    if not after.any():
        return {"at_s": t_fail, "trough": None, "plateau": None, "restabilize_s": None}
    ta, ca = t[after], coverage[after]
    plateau = float(ca[ta >= ta[-1] - plateau_s].mean())
    outside = np.abs(ca - plateau) > band
    if not outside.any():
        settle = 0.0
    elif outside[-1]:
        settle = None
    else:
        last_out = int(np.nonzero(outside)[0][-1])
        settle = float(ta[last_out + 1] - t_fail)
    return {"at_s": t_fail, "trough": float(ca.min()), "plateau": plateau, "restabilize_s": settle}


def summarize(rows: Sequence[dict], events: Sequence[dict], speedup: float) -> dict:
    """summary.json from metrics rows and fired events ({"t", "type", ...})."""
    if not rows:
        raise ValueError("no metrics recorded")
    t = np.array([r["t"] for r in rows], dtype=float)
    cov = np.array([r["coverage"] for r in rows], dtype=float)
    fails = sorted(e["t"] for e in events if e.get("type") == "node_failure")
    recoveries = []
    for i, tf in enumerate(fails):
        t_next = fails[i + 1] if i + 1 < len(fails) else None
        recoveries.append(failure_recovery(t, cov, tf, t_next))
    return {
        "coverage_mean": float(cov.mean()),
        "coverage_min": float(cov.min()),
        "duration_s": float(t[-1] - t[0]) if len(t) > 1 else 0.0,
        "speedup": speedup,
        "events": list(events),
        "node_failures": recoveries,
    }


def sensing_lag(traces: Sequence[Sequence[dict]]) -> dict:
    """How stale the users were that the agents decided on: for each decision at second t
    that saw sensing (agent traces, `sense_t`), t - sense_t. A SITL run that cannot keep
    up with its speedup shows it here first (the bus backs up), long before coverage."""
    lags = [r["t"] - r["sense_t"] for rows in traces for r in rows if r.get("decided") and r.get("sense_t") is not None]
    if not lags:
        return {"decisions": 0, "mean_s": None, "max_s": None}
    return {"decisions": len(lags), "mean_s": round(float(np.mean(lags)), 3), "max_s": float(max(lags))}
