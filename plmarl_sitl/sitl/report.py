"""`plmarl report DIR`: plots of a recorded run, and its summary.

Reads metrics.jsonl, events.jsonl and summary.json from DIR (what `plmarl swarm up
--out DIR` writes) and draws, as PNGs in DIR: coverage over time with every event named
and a reference from the twin (`report_plots`), the P-AoI heat map UAV x time
(`report_plots`) and the map of the run (`report_map`). metrics.csv (`report_csv`) and
report.html (`report_html`) are written beside them.
"""

from __future__ import annotations

import json
from pathlib import Path

from plmarl_sitl.errors import UserError


def read_jsonl(path: Path) -> list[dict]:
    """Rows of a JSONL file; a malformed line names the file and line number."""
    rows = []
    try:
        lines = path.read_text().splitlines()
    except OSError as exc:
        raise UserError(f"{path}: cannot read ({exc.strerror})") from exc
    for i, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            rows.append(json.loads(line))
        except json.JSONDecodeError as exc:
            raise UserError(f"{path}:{i}: not valid JSON ({exc.msg})") from exc
    return rows


def load_run(run_dir: Path) -> tuple[list[dict], list[dict], dict | None]:
    if not run_dir.is_dir():
        raise UserError(f"{run_dir}: no such run directory")
    metrics = read_jsonl(run_dir / "metrics.jsonl")
    if not metrics:
        raise UserError(f"{run_dir / 'metrics.jsonl'}: no metrics recorded")
    for i, row in enumerate(metrics, 1):
        missing = {"t", "coverage", "uavs"} - set(row)
        if missing:
            raise UserError(f"{run_dir / 'metrics.jsonl'}:{i}: missing keys {sorted(missing)}")
    events_path = run_dir / "events.jsonl"
    events = read_jsonl(events_path) if events_path.exists() else []
    summary_path = run_dir / "summary.json"
    summary = None
    if summary_path.exists():
        try:
            summary = json.loads(summary_path.read_text())
        except json.JSONDecodeError as exc:
            raise UserError(f"{summary_path}: not valid JSON ({exc.msg}); delete it to recompute it from metrics.jsonl") from exc
    return metrics, events, summary


def draw(run_dir: Path, metrics: list[dict], events: list[dict], summary: dict | None = None,
         twin: dict | None = None) -> list[Path]:
    """Write coverage.png, aoi.png and trajectories.png into run_dir; return their paths.
    `twin`: the twin's coverage of the same mission, seed and policy ({"coverage", "label"})."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from plmarl_sitl.sitl.report_map import run_mission, trajectory_figure
    from plmarl_sitl.sitl.report_plots import aoi_figure, coverage_figure

    mission = run_mission(run_dir)
    horizon = mission.signalling.drop_after_missed * mission.signalling.tup_s if mission is not None else None
    figures = {
        "coverage.png": lambda: coverage_figure(plt, metrics, events, summary, twin),
        "aoi.png": lambda: aoi_figure(plt, metrics, events, horizon),
        "trajectories.png": lambda: trajectory_figure(plt, run_dir, metrics, events),
    }
    out = []
    for name, make in figures.items():
        fig = make()
        out.append(run_dir / name)
        fig.savefig(out[-1], dpi=120, bbox_inches="tight")  # legends sit outside the axes
        plt.close(fig)
    return out


def print_summary(summary: dict, console, title: str) -> None:  # noqa: ANN001 - rich Console
    from rich.table import Table

    from plmarl_sitl.sitl.summary import transient_label

    t = Table(title=title)
    t.add_column("metric")
    t.add_column("value", justify="right")
    t.add_row("coverage mean", f"{summary['coverage_mean']:.3f}")
    t.add_row("coverage min", f"{summary['coverage_min']:.3f}")
    t.add_row("duration", f"{summary['duration_s']:.0f} s (speedup {summary['speedup']})")
    if summary.get("mission_wall_s"):  # a run just flown (not in summary.json: it is wall-clock)
        t.add_row("mission wall time", f"{summary['mission_wall_s']:.1f} s ({summary['achieved_speedup']:.1f}x achieved)")
    t.add_row("events", str(len(summary["events"])))
    for f in summary.get("node_failures", []):
        who = f" (UAV {f['uav']})" if f.get("uav") is not None else ""
        t.add_row(f"failure at {f['at_s']:.0f} s{who}", transient_label(f))
    console.print(t)
