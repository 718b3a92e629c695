"""`plmarl report DIR`: plots of a recorded run, and its summary.

Reads metrics.jsonl, events.jsonl and summary.json from DIR (what `plmarl swarm up
--out DIR` writes) and draws coverage over time with the events marked, the per-UAV
maximum P-AoI over time, and the trajectories, as PNGs in DIR.
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


def draw(run_dir: Path, metrics: list[dict], events: list[dict]) -> list[Path]:
    """Write coverage.png, aoi.png and trajectories.png into run_dir; return their paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = [r["t"] for r in metrics]
    out = []

    fig, ax = plt.subplots(figsize=(8, 3.5))
    ax.plot(t, [r["coverage"] for r in metrics], lw=1.5, label="coverage C(t)")
    for ev in events:
        ax.axvline(ev["t"], color="tab:red", ls="--", lw=1)
        ax.annotate(ev.get("type", "event"), (ev["t"], 0.02), rotation=90, fontsize=8, color="tab:red", va="bottom", ha="right")
    ax.set(xlabel="sim time [s]", ylabel="coverage", ylim=(0, 1.02), title="Coverage over time")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    out.append(run_dir / "coverage.png")
    fig.savefig(out[-1], dpi=120)
    plt.close(fig)

    ids = sorted({u["id"] for r in metrics for u in r["uavs"]})
    fig, ax = plt.subplots(figsize=(8, 3.5))
    for uid in ids:
        pts = [(r["t"], u.get("aoi_max")) for r in metrics for u in r["uavs"] if u["id"] == uid and u.get("aoi_max") is not None]
        if pts:
            ax.plot(*zip(*pts, strict=True), lw=1, label=f"UAV {uid}")
    ax.set(xlabel="sim time [s]", ylabel="max P-AoI [s]", title="Perception age of information")
    ax.grid(alpha=0.3)
    if ids:
        ax.legend(fontsize=7, ncol=min(len(ids), 5))
    fig.tight_layout()
    out.append(run_dir / "aoi.png")
    fig.savefig(out[-1], dpi=120)
    plt.close(fig)

    fig = trajectory_figure(plt, run_dir, metrics)
    out.append(run_dir / "trajectories.png")
    fig.savefig(out[-1], dpi=120, bbox_inches="tight")  # the legend sits outside the axes
    plt.close(fig)
    return out


def trajectory_figure(plt, run_dir: Path, metrics: list[dict]):  # noqa: ANN001, ANN201 - pyplot -> Figure
    """The UAVs' tracks over the run's users (at t = 0 and at the end) and the U2U links of
    the last second, with a legend; without the run's mission.yaml, the tracks alone."""
    ids = sorted({u["id"] for r in metrics for u in r["uavs"]})
    fig, ax = plt.subplots(figsize=(9, 6))
    mission = _run_mission(run_dir)
    if mission is not None:
        first, last = replay_users(mission, _run_seed(run_dir, mission), int(metrics[-1]["t"]))
        ax.scatter(first[:, 1], first[:, 0], s=3, color="0.75", label="users at t = 0")
        ax.scatter(last[:, 1], last[:, 0], s=3, color="0.35", label=f"users at t = {metrics[-1]['t']:g} s")
        _draw_links(ax, metrics[-1], mission)
        ax.set(xlim=(0, mission.area.east_m), ylim=(0, mission.area.north_m))
    for k, uid in enumerate(ids):
        pts = [u["pos_ned"] for r in metrics for u in r["uavs"] if u["id"] == uid and u.get("pos_ned") is not None]
        if pts:
            label = f"UAV {uid}" if len(ids) <= 8 else ("UAVs (one colour each)" if k == 0 else None)
            line, = ax.plot([p[1] for p in pts], [p[0] for p in pts], lw=1, label=label)
            ax.plot(pts[-1][1], pts[-1][0], "o", ms=5, color=line.get_color())
    ax.plot([], [], "o", ms=5, color="0.2", label="UAV at the end")
    ax.set(xlabel="east [m]", ylabel="north [m]", title="Trajectories (mission frame)")
    ax.set_aspect("equal")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    fig.tight_layout()
    return fig


def _run_mission(run_dir: Path):  # noqa: ANN202 - Mission | None
    """The run's own copy of its mission (written by `plmarl swarm up`), or None."""
    from plmarl_sitl.mission import load_mission

    try:
        return load_mission(run_dir / "mission.yaml")
    except (OSError, UserError):  # a bad mission file is a ConfigError
        return None


def _run_seed(run_dir: Path, mission) -> int:  # noqa: ANN001
    try:
        return int(json.loads((run_dir / "summary.json").read_text())["seed"])
    except (OSError, KeyError, TypeError, ValueError):
        return mission.seed


def replay_users(mission, seed: int, seconds: int):  # noqa: ANN001, ANN201 - Mission -> (U, 2) arrays
    """(north, east) of every user at t = 0 and after `seconds`: the users depend only on
    the mission and the seed (the SITL world and the twin step them with a generator of
    their own, `sitl/world.py`), so the run's users are replayed exactly, not recorded."""
    import torch

    from plmarl_sitl.model.users import init_users, step_users

    gen = torch.Generator().manual_seed(seed)
    users = init_users(mission, 1, gen, torch.float32)
    first = users.xy[0].numpy().copy()
    for _ in range(seconds):
        users = step_users(users, mission, mission.timing.dt_s, gen)
    return first, users.xy[0].numpy()


def _draw_links(ax, row: dict, mission) -> None:  # noqa: ANN001 - matplotlib Axes, Mission
    """U2U links at the row's second, exactly as the world had them: `link_mask` (within
    R_comm AND SINR >= Gamma, with the other live UAVs interfering) on the live UAVs' 3-D
    positions. A pair heard both ways is an edge of the swarm graph (lambda_2); a pair heard
    one way only is drawn dotted."""
    import torch

    from plmarl_sitl.model.graph import link_mask

    live = [u["pos_ned"] for u in row["uavs"] if u.get("alive", True) and u.get("pos_ned") is not None]
    if len(live) < 2:
        return
    pos = torch.tensor(live, dtype=torch.float32)  # the world's dtype (`SitlWorld.positions`)
    rx, _ = link_mask(pos, torch.ones(len(live), dtype=torch.bool), mission.channel, mission.radii.comm_m)
    labels = {True: f"U2U link (R_comm and SINR) at t = {row['t']:g} s", False: f"one-way U2U link at t = {row['t']:g} s"}
    for a in range(len(live)):
        for b in range(a + 1, len(live)):
            ab, ba = bool(rx[a, b]), bool(rx[b, a])
            if not (ab or ba):
                continue
            pa, pb = live[a], live[b]
            both = ab and ba
            ax.plot([pa[1], pb[1]], [pa[0], pb[0]], ls="--" if both else ":", lw=0.8, color="tab:gray", label=labels[both])
            labels[both] = None


def print_summary(summary: dict, console, title: str) -> None:  # noqa: ANN001 - rich Console
    from rich.table import Table

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
        settle = "never" if f["restabilize_s"] is None else f"{f['restabilize_s']:.0f} s"
        trough = "-" if f["trough"] is None else f"{f['trough']:.3f}"
        t.add_row(f"failure at {f['at_s']:.0f} s", f"trough {trough}, re-stabilised after {settle}")
    console.print(t)
