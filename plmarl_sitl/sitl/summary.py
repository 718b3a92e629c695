"""The summary of a recorded run (summary.json), computed from metrics.jsonl rows.

A row is one sim second: {"t", "coverage", "lambda2", "messages", "uavs": [{"id",
"alive", "pos_ned", "vel_ned", "aoi_max"}, ...]}. For each node failure at t_f (or a UAV
an autopilot fault took out of the mission, "uav_failed"), over the seconds from t_f to
the end of the run (or to the next failure):
* pre_event: the mean coverage over the `PRE_S` seconds before t_f;
* trough: the lowest coverage from t_f on; end: the last coverage of the window;
* band: how close to pre_event counts as recovered: max(`BAND_ABS`, `BAND_REL` x pre_event);
* restabilize_s: seconds from t_f until coverage is back within pre_event - band and stays
  there for at least `HOLD_S` seconds (None if it never does: "did not recover"). Above
  the pre-event level counts as recovered too;
* plateau / settle_s: the mean coverage over the last `PLATEAU_S` seconds of the window,
  and the seconds until coverage stays within `BAND_ABS` of it (None if it never does):
  how fast the swarm settled, whether or not at its old level.
`transient_label` turns a record into the one line the summary and the report print.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

PRE_S = 10.0
BAND_ABS = 0.02
BAND_REL = 0.05
HOLD_S = 10.0
PLATEAU_S = 30.0


def failure_recovery(t: np.ndarray, coverage: np.ndarray, t_fail: float, t_end: float | None = None) -> dict:
    """Pre-event level, trough, end, and whether (and when) coverage recovered after a
    failure at `t_fail`; see the module docstring for the definitions."""
    t_end = float(t[-1]) if t_end is None else t_end
    after = (t >= t_fail) & (t <= t_end)
    before = (t < t_fail) & (t >= t_fail - PRE_S)
    pre = float(coverage[before].mean()) if before.any() else None
    rec = {"at_s": t_fail, "until_s": t_end, "pre_event": pre, "trough": None, "end": None, "band": None, "restabilize_s": None,
           "plateau": None, "settle_s": None}
    if not after.any():
        return rec
    ta, ca = t[after], coverage[after]
    plateau = float(ca[ta >= ta[-1] - PLATEAU_S].mean())
    rec |= {"trough": float(ca.min()), "end": float(ca[-1]), "plateau": plateau,
            "settle_s": _first_stay(ta, np.abs(ca - plateau) <= BAND_ABS, t_fail, 0.0)}
    if pre is not None:
        band = max(BAND_ABS, BAND_REL * pre)
        rec["band"] = band
        rec["restabilize_s"] = _first_stay(ta, ca >= pre - band, t_fail, HOLD_S)
    return rec


def _first_stay(t: np.ndarray, ok: np.ndarray, t0: float, hold_s: float) -> float | None:
    """Seconds from t0 to the start of the first run of `ok` that lasts to the end of the
    window and at least `hold_s` seconds; None if there is none."""
    if not ok[-1]:
        return None
    bad = np.nonzero(~ok)[0]
    start = 0 if len(bad) == 0 else int(bad[-1]) + 1
    if t[-1] - t[start] < hold_s:
        return None
    return float(t[start] - t0)


def transient_label(rec: dict) -> str:
    """The honest one-liner for a failure record: "re-stabilised" only when coverage came
    back within the band of its pre-event level and held there."""
    if rec.get("trough") is None:
        return "no data after the failure"
    if rec.get("pre_event") is None:
        return f"no data before the failure (trough {rec['trough']:.3f}, end {rec['end']:.3f})"
    if rec["restabilize_s"] is not None:
        return (f"re-stabilised after {rec['restabilize_s']:.0f} s (back within {rec['band']:.3f} of the pre-event "
                f"{rec['pre_event']:.3f}, held >= {HOLD_S:.0f} s; trough {rec['trough']:.3f})")
    return f"did not recover (trough {rec['trough']:.3f}, end {rec['end']:.3f}; pre-event {rec['pre_event']:.3f})"


def summarize(rows: Sequence[dict], events: Sequence[dict], speedup: float) -> dict:
    """summary.json from metrics rows and fired events ({"t", "type", ...})."""
    if not rows:
        raise ValueError("no metrics recorded")
    t = np.array([r["t"] for r in rows], dtype=float)
    cov = np.array([r["coverage"] for r in rows], dtype=float)
    fails = sorted((e for e in events if e.get("type") in ("node_failure", "uav_failed")), key=lambda e: e["t"])
    recoveries = []
    for i, ev in enumerate(fails):
        t_next = fails[i + 1]["t"] if i + 1 < len(fails) else None
        rec = {**failure_recovery(t, cov, ev["t"], t_next), "uav": ev.get("uav"), "type": ev["type"]}
        rec["label"] = transient_label(rec)
        recoveries.append(rec)
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
