"""metrics.csv: the run's per-second metrics as one wide table, for a spreadsheet, pandas
or pgfplots. The same numbers as metrics.jsonl, one row per mission second:

    t               mission second
    coverage        C(t), the share of users covered
    lambda2         algebraic connectivity of the live swarm's U2U graph (0: split)
    messages        state messages the agents sent during that second
    alive           live UAVs
    uavI_alive      1 while UAV I counts, 0 once it is lost
    uavI_north, uavI_east, uavI_alt   position in the mission frame, metres (alt = -down)
    uavI_speed      ground-frame speed, m/s
    uavI_aoi_max    largest P-AoI among the neighbours UAV I holds, s (empty: none held)

An unknown value (no position reported, no neighbour held) is an empty cell.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

SWARM_COLUMNS = ("t", "coverage", "lambda2", "messages", "alive")
UAV_COLUMNS = ("alive", "north", "east", "alt", "speed", "aoi_max")


def header(ids: list[int]) -> list[str]:
    return [*SWARM_COLUMNS, *(f"uav{i}_{c}" for i in ids for c in UAV_COLUMNS)]


def _num(x: float | None, digits: int) -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return ""
    return f"{x:.{digits}f}".rstrip("0").rstrip(".") if digits else str(int(x))


def _uav_cells(u: dict | None) -> list[str]:
    if u is None:
        return [""] * len(UAV_COLUMNS)
    pos, vel = u.get("pos_ned"), u.get("vel_ned")
    speed = math.sqrt(sum(v * v for v in vel)) if vel is not None else None
    return [
        "1" if u.get("alive", True) else "0",
        _num(pos[0], 2) if pos is not None else "", _num(pos[1], 2) if pos is not None else "",
        _num(-pos[2], 2) if pos is not None else "",
        _num(speed, 3), _num(u.get("aoi_max"), 1),
    ]


def write_metrics_csv(path: Path, metrics: list[dict]) -> Path:
    """Write metrics.jsonl rows as metrics.csv (see the module docstring for the columns)."""
    ids = sorted({u["id"] for r in metrics for u in r["uavs"]})
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header(ids))
        for r in metrics:
            by_id = {u["id"]: u for u in r["uavs"]}
            alive = sum(1 for u in r["uavs"] if u.get("alive", True))
            w.writerow([_num(r["t"], 3), _num(r["coverage"], 5), _num(r.get("lambda2"), 5), _num(r.get("messages"), 0),
                        str(alive), *(cell for i in ids for cell in _uav_cells(by_id.get(i)))])
    return path
