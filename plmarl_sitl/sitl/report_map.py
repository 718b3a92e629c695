"""The map of a run (trajectories.png): the UAVs' tracks over the run's users and their
clusters, the launch line, where each lost UAV stopped, and the U2U links over time.

The users are replayed, not recorded: they depend only on the mission and the seed
(`replay_users`). The links are recomputed from the recorded positions with the world's
own `link_mask`, so they are exactly the links the world had at those seconds.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from plmarl_sitl.errors import UserError
from plmarl_sitl.sitl.links import u2u_links
from plmarl_sitl.sitl.report_events import lost_at

LINK_EVERY_S = 20  # the faded links: one snapshot every this many mission seconds


def run_mission(run_dir: Path):  # noqa: ANN201 - Mission | None
    """The run's own copy of its mission (written by `plmarl swarm up`), or None."""
    from plmarl_sitl.mission import load_mission

    try:
        return load_mission(run_dir / "mission.yaml")
    except (OSError, UserError):  # a bad mission file is a ConfigError
        return None


def replay_users(mission, seed: int, seconds: int):  # noqa: ANN001, ANN201 - Mission -> (U, 2) arrays
    """(north, east) of every user at t = 0 and after `seconds`: the users depend only on
    the mission and the seed (the SITL world and the twin step them with a generator of
    their own, `sitl/world.py`), so the run's users are replayed exactly, not recorded."""
    first, last, _ = replay_users_and_clusters(mission, seed, seconds)
    return first, last


def replay_users_and_clusters(mission, seed: int, seconds: int):  # noqa: ANN001, ANN201
    """`replay_users` and the (C, 2) (north, east) centres of the users' clusters."""
    import torch

    from plmarl_sitl.model.users import init_users, step_users

    gen = torch.Generator().manual_seed(seed)
    users = init_users(mission, 1, gen, torch.float32)
    first = users.xy[0].numpy().copy()
    centres = np.unique(users.home[0].transpose(0, 1).numpy(), axis=0)
    for _ in range(seconds):
        users = step_users(users, mission, mission.timing.dt_s, gen)
    return first, users.xy[0].numpy(), centres


def link_pairs(row: dict, mission) -> tuple[list, list]:  # noqa: ANN001 - Mission
    """([(pa, pb)] heard both ways, [(pa, pb)] heard one way) at the row's second: the
    positions of the pairs `links.u2u_links` finds."""
    pos = {u["id"]: u["pos_ned"] for u in row["uavs"]}
    both, one = u2u_links(row["uavs"], mission)
    return [(pos[i], pos[j]) for i, j in both], [(pos[i], pos[j]) for i, j in one]


def _draw_links(ax, metrics: list[dict], mission) -> None:  # noqa: ANN001 - matplotlib Axes, Mission
    """The links of every LINK_EVERY_S-th second, faded, and those of the last second: dashed
    both ways, dotted one way."""
    last = metrics[-1]
    faded_label = f"U2U links every {LINK_EVERY_S} s (faded)"
    for row in metrics[:-1]:
        if row["t"] % LINK_EVERY_S != 0:
            continue
        both, _ = link_pairs(row, mission)
        for pa, pb in both:
            ax.plot([pa[1], pb[1]], [pa[0], pb[0]], ls="-", lw=0.8, color="tab:gray", alpha=0.18, label=faded_label, zorder=1)
            faded_label = None
    both, one = link_pairs(last, mission)
    labels = {True: f"U2U link (R_comm and SINR) at t = {last['t']:g} s", False: f"one-way U2U link at t = {last['t']:g} s"}
    for pairs, two_way in ((both, True), (one, False)):
        for pa, pb in pairs:
            ax.plot([pa[1], pb[1]], [pa[0], pb[0]], ls="--" if two_way else ":", lw=0.9, color="0.3", label=labels[two_way],
                    zorder=2)
            labels[two_way] = None


def _draw_launch(ax, mission) -> None:  # noqa: ANN001
    from plmarl_sitl.twin.env import launch_positions

    slots = launch_positions(mission, 0.0).numpy()
    ax.plot(slots[:, 1], slots[:, 0], "-", color="k", lw=2.5, alpha=0.55, zorder=2,
            label=f"launch line ({len(slots)} slots, {mission.launch.spacing_m:g} m apart)")
    ax.plot(slots[:, 1], slots[:, 0], "|" if abs(mission.launch.direction()[0]) < 0.5 else "_", color="k", ms=6, zorder=2)
    ax.annotate("UAV 0", (slots[0, 1], slots[0, 0]), xytext=(0, -12), textcoords="offset points", fontsize=7, ha="center")


def trajectory_figure(plt, run_dir: Path, metrics: list[dict], events: list[dict] | None = None):  # noqa: ANN001, ANN201
    """The UAVs' tracks (each labelled with its id at its end), a lost UAV's track ending in
    a red X where it stopped counting; with the run's mission.yaml also the users (t = 0 and
    the end), their cluster centres, the launch line and the U2U links over time."""
    events = events or []
    ids = sorted({u["id"] for r in metrics for u in r["uavs"]})
    fig, ax = plt.subplots(figsize=(9.5, 6.5))
    mission = run_mission(run_dir)
    if mission is not None:
        first, last, centres = replay_users_and_clusters(mission, run_seed(run_dir, mission), int(metrics[-1]["t"]))
        ax.scatter(first[:, 1], first[:, 0], s=2, color="0.8", label="users at t = 0", zorder=0)
        ax.scatter(last[:, 1], last[:, 0], s=2, color="0.55", label=f"users at t = {metrics[-1]['t']:g} s", zorder=0)
        ax.plot(centres[:, 1], centres[:, 0], "+", ms=14, mew=1.6, color="tab:cyan", ls="none",
                label=f"user cluster centres ({len(centres)})", zorder=1)
        _draw_launch(ax, mission)
        _draw_links(ax, metrics, mission)
        ax.set(xlim=(0, mission.area.east_m), ylim=(0, mission.area.north_m))
    colours = plt.get_cmap("tab10" if len(ids) <= 10 else "tab20")
    dead_at = _dead_at(metrics)
    named = lost_at(events)
    for k, uid in enumerate(ids):
        pts = [(r["t"], u["pos_ned"]) for r in metrics for u in r["uavs"]
               if u["id"] == uid and u.get("pos_ned") is not None and (uid not in dead_at or r["t"] <= dead_at[uid])]
        if not pts:
            continue
        colour = colours(k % colours.N)
        label = f"UAV {uid}" if len(ids) <= 8 else ("UAV tracks (one colour each)" if k == 0 else None)
        north = [p[0] for _, p in pts]
        east = [p[1] for _, p in pts]
        ax.plot(east, north, lw=1.2, color=colour, label=label, zorder=3)
        if uid in dead_at:
            t_lost, what = named.get(uid, (dead_at[uid], f"UAV {uid} lost"))
            ax.plot(east[-1], north[-1], "X", ms=11, color="tab:red", mec="k", mew=0.8, zorder=5)
            ax.annotate(f"{what} (t = {t_lost:g} s)", (east[-1], north[-1]), xytext=(7, 6), textcoords="offset points",
                        fontsize=8, color="tab:red", fontweight="bold", zorder=6,
                        bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "tab:red", "lw": 0.6, "alpha": 0.85})
        else:
            ax.plot(east[-1], north[-1], "o", ms=5, color=colour, mec="k", mew=0.5, zorder=4)
            ax.annotate(str(uid), (east[-1], north[-1]), xytext=(4, 3), textcoords="offset points", fontsize=7, zorder=6)
    ax.plot([], [], "o", ms=5, color="0.6", mec="k", mew=0.5, label="UAV at the end (its id beside it)")
    if dead_at:
        ax.plot([], [], "X", ms=9, color="tab:red", mec="k", mew=0.8, ls="none", label="lost UAV: where it stopped")
    ax.set(xlabel="east [m]", ylabel="north [m]", title="Trajectories (mission frame)")
    ax.set_aspect("equal")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0, markerscale=0.8)
    fig.tight_layout()
    return fig


def _dead_at(metrics: list[dict]) -> dict[int, float]:
    """{uav: the last second it was alive} for the UAVs the run lost (from the recorded
    `alive` flags, whatever took them out)."""
    last_alive: dict[int, float] = {}
    dead: set[int] = set()
    for r in metrics:
        for u in r["uavs"]:
            if u.get("alive", True):
                last_alive[u["id"]] = r["t"]
                dead.discard(u["id"])
            else:
                dead.add(u["id"])
    return {uid: last_alive.get(uid, metrics[0]["t"]) for uid in dead}


def run_seed(run_dir: Path, mission) -> int:  # noqa: ANN001
    import json

    try:
        return int(json.loads((run_dir / "summary.json").read_text())["seed"])
    except (OSError, KeyError, TypeError, ValueError):
        return mission.seed
