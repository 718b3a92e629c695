"""The summary of a recorded run (summary.json), computed from metrics.jsonl rows.

A row is one sim second: {"t", "coverage", "lambda2", "messages", "uavs": [{"id",
"alive", "pos_ned", "vel_ned", "aoi_max"}, ...]}. For each node failure at t_f (or a UAV
an autopilot fault took out of the mission, "uav_failed"):
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
    fails = sorted(e["t"] for e in events if e.get("type") in ("node_failure", "uav_failed"))
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


def timeliness(traces: Sequence[Sequence[dict]], t0_boot_s: float | Sequence[float] | None) -> dict:
    """Did the SITL swarm keep up with its speedup? From the agents' traces:
    - decision_delay_s: vehicle seconds from mission second t to the moment the agent
      acted on it (the twin acts at t exactly); bus and CPU latency, x the speedup;
    - sensing_age_s: t minus the second of the users that decision saw.
    Each as {"p50", "p95", "max"} over all decisions (None without decisions). `t0_boot_s` is
    the mission start on the agents' vehicle clock: one for all (a shared SITL clock), or one
    per trace (vehicles with clocks of their own)."""
    t0s = [t0_boot_s] * len(traces) if t0_boot_s is None or isinstance(t0_boot_s, (int, float)) else list(t0_boot_s)
    decisions = [(r, t0) for rows, t0 in zip(traces, t0s, strict=True) for r in rows if r.get("decided")]

    def stats(xs: list[float]) -> dict | None:
        if not xs:
            return None
        a = np.asarray(xs, dtype=float)
        return {k: round(float(v), 3) for k, v in (("p50", np.median(a)), ("p95", np.quantile(a, 0.95)), ("max", a.max()))}

    delays = [r["boot_s"] - (t0 + r["t"]) for r, t0 in decisions if t0 is not None and "boot_s" in r]
    ages = [r["t"] - r["sense_t"] for r, _ in decisions if r.get("sense_t") is not None]
    return {"decisions": len(decisions), "decision_delay_s": stats(delays), "sensing_age_s": stats(ages)}
