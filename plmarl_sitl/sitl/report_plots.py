"""The time plots of `plmarl report`: coverage (with lambda_2, the events and a reference
from the twin) and the P-AoI heat map. Each function takes pyplot and returns a Figure,
so the caller chooses the backend and where it is saved.
"""

from __future__ import annotations

import math

import numpy as np

from plmarl_sitl.sitl.report_events import Marker, lost_at, markers
from plmarl_sitl.sitl.summary import transient_label

# One colour per kind of event, the same in every plot; losses are red.
EVENT_COLOURS = {
    "node_failure": "tab:red", "uav_failed": "tab:red", "agent_failed": "tab:red", "motor_failure": "tab:red",
    "link_blackout": "tab:purple", "broker_outage": "tab:brown", "tup_change": "tab:green",
    "gnss_noise": "tab:olive", "gps_loss": "tab:pink",
}
SITL_COLOUR = "tab:blue"
TWIN_COLOUR = "tab:orange"


def _series(metrics: list[dict], key: str) -> tuple[np.ndarray, np.ndarray]:
    t = np.array([r["t"] for r in metrics], dtype=float)
    v = np.array([r.get(key) if r.get(key) is not None else math.nan for r in metrics], dtype=float)
    return t, v


def mark_events(ax, marks: list[Marker], *, labels: bool) -> None:  # noqa: ANN001 - matplotlib Axes
    """Instants as dashed vertical lines, windows as shaded spans; with `labels`, each
    event's name along its line at the bottom of the axes (events of the same second share
    one label)."""
    by_t: dict[float, list[Marker]] = {}
    for m in marks:
        colour = EVENT_COLOURS.get(m.kind, "0.3")
        if m.end is not None and m.end > m.t:
            ax.axvspan(m.t, m.end, color=colour, alpha=0.12, lw=0)
        ax.axvline(m.t, color=colour, ls="--", lw=1)
        by_t.setdefault(m.t, []).append(m)
    if not labels:
        return
    for t, group in by_t.items():
        ax.annotate("\n".join(m.label for m in group), (t, 0.03), xycoords=("data", "axes fraction"), rotation=90,
                    fontsize=8, color=EVENT_COLOURS.get(group[0].kind, "0.3"), va="bottom", ha="right",
                    xytext=(-2, 0), textcoords="offset points",
                    bbox={"boxstyle": "square,pad=0.1", "fc": "white", "ec": "none", "alpha": 0.8})


def coverage_figure(plt, metrics: list[dict], events: list[dict], summary: dict | None = None,  # noqa: ANN001, ANN201
                    twin: dict | None = None):
    """Coverage C(t) of the run, the twin's C(t) of the same mission, seed and policy when
    given (`twin`: {"coverage": [C(1), C(2), ...], "label": str}), every event marked and
    named, the recovery band of each failure and its honest label; lambda_2 below."""
    t, cov = _series(metrics, "coverage")
    _, lam2 = _series(metrics, "lambda2")
    marks = markers(events, float(t[-1]))
    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(9, 5.6), sharex=True, gridspec_kw={"height_ratios": [3, 1.2]})
    # The SITL line is drawn wide and the twin's dashed and thin on top: where they coincide
    # (a lockstep run of the twin's controller usually does), both stay visible.
    ax.plot(t, cov, lw=3.0, color=SITL_COLOUR, alpha=0.75, label=f"SITL run (mean {np.nanmean(cov):.3f})")
    notes = []
    if twin is not None and twin.get("coverage"):
        tc = np.asarray(twin["coverage"], dtype=float)
        tt = np.arange(1, len(tc) + 1, dtype=float)  # the twin's C(t) after step t, t = 1 .. T
        keep = tt <= t[-1]
        ax.plot(tt[keep], tc[keep], lw=1.1, ls="--", color=TWIN_COLOUR,
                label=f"{twin.get('label', 'twin')} (mean {np.mean(tc[keep]):.3f})")
        if twin.get("note"):
            notes.append(twin["note"])
    banded = False
    for rec in (summary or {}).get("node_failures", []):
        who = f"UAV {rec['uav']}" if rec.get("uav") is not None else "failure"
        notes.append(f"{who} at {rec['at_s']:.0f} s: {rec.get('label') or transient_label(rec)}")
        if rec.get("pre_event") is None or rec.get("band") is None:
            continue
        ax.fill_between([rec["at_s"], rec.get("until_s", t[-1])], rec["pre_event"] - rec["band"],
                        min(1.0, rec["pre_event"] + rec["band"]), color="tab:green", alpha=0.15, lw=0,
                        label=None if banded else "recovery band: pre-event level +- band")
        banded = True
    mark_events(ax, marks, labels=True)
    ax.set(ylabel="coverage C(t)", ylim=(0, 1.02))
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="lower left", bbox_to_anchor=(0.0, 1.02), ncol=1, borderaxespad=0, frameon=False)
    ax2.plot(t, lam2, lw=1.2, color="0.25")
    mark_events(ax2, marks, labels=False)
    ax2.set(xlabel="mission time [s]", ylabel="lambda_2")
    ax2.set_ylim(bottom=0)
    ax2.grid(alpha=0.3)
    fig.suptitle("Coverage over time (below: connectivity lambda_2; 0 = the swarm is split)", fontsize=11)
    if notes:
        fig.text(0.01, 0.0, "\n".join(notes), fontsize=8, va="top", ha="left")
    fig.tight_layout()
    return fig


def aoi_figure(plt, metrics: list[dict], events: list[dict], horizon_s: float | None = None):  # noqa: ANN001, ANN201
    """A heat map UAV x time of each UAV's largest P-AoI among the neighbours it holds:
    readable at N = 20 where lines overlap. Seconds a live UAV held no neighbour and seconds
    after it was lost have colours of their own; each loss is marked on its UAV's row."""
    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Patch

    t = np.array([r["t"] for r in metrics], dtype=float)
    ids = sorted({u["id"] for r in metrics for u in r["uavs"]})
    row_of = {uid: k for k, uid in enumerate(ids)}
    aoi = np.full((len(ids), len(t)), math.nan)
    dead = np.zeros((len(ids), len(t)), dtype=bool)
    for j, r in enumerate(metrics):
        for u in r["uavs"]:
            k = row_of[u["id"]]
            if not u.get("alive", True):
                dead[k, j] = True
            elif u.get("aoi_max") is not None:
                aoi[k, j] = u["aoi_max"]
    n = len(ids)
    fig, ax = plt.subplots(figsize=(9, 1.9 + 0.24 * max(n, 3)))
    dt = float(t[1] - t[0]) if len(t) > 1 else 1.0
    extent = (t[0] - dt / 2, t[-1] + dt / 2, n - 0.5, -0.5)
    vmax = horizon_s if horizon_s else (np.nanmax(aoi) if np.isfinite(aoi).any() else 1.0)
    ax.imshow(np.where(np.isnan(aoi) & ~dead, 1.0, np.nan), aspect="auto", extent=extent, interpolation="nearest",
              cmap=ListedColormap(["0.85"]), vmin=0, vmax=1)
    ax.imshow(np.where(dead, 1.0, np.nan), aspect="auto", extent=extent, interpolation="nearest",
              cmap=ListedColormap(["0.2"]), vmin=0, vmax=1)
    im = ax.imshow(aoi, aspect="auto", extent=extent, interpolation="nearest", cmap="viridis", vmin=0, vmax=vmax)
    cbar = fig.colorbar(im, ax=ax, pad=0.015)
    cbar.set_label("max P-AoI of the neighbours held [s]", fontsize=8)
    step = 1 if n <= 24 else math.ceil(n / 24)
    ax.set_yticks(range(0, n, step), [f"UAV {ids[k]}" for k in range(0, n, step)], fontsize=7 if n > 8 else 8)
    for marker in markers(events, float(t[-1])):
        if marker.uav is not None:  # a UAV's loss is marked on its row below
            continue
        # Events of the swarm (blackouts, outages, T_up changes ...): white dashed lines at the
        # start (and end) that show on every colour of the map, named at the top.
        for x in (marker.t,) if marker.end is None else (marker.t, marker.end):
            ax.axvline(x, color="white", ls="--", lw=1.2)
        ax.annotate(marker.label, (marker.t, -0.5), xytext=(3, -3), textcoords="offset points", fontsize=7, color="white",
                    va="top", ha="left", bbox={"boxstyle": "square,pad=0.15", "fc": "0.15", "ec": "none", "alpha": 0.7})
    for uid, (tf, label) in lost_at(events).items():
        if uid in row_of:
            ax.plot([tf], [row_of[uid]], marker="X", ms=9, color="tab:red", mec="white", mew=1, ls="none")
            ax.annotate(label, (tf, row_of[uid]), xytext=(6, 0), textcoords="offset points", fontsize=8, color="white",
                        va="center", fontweight="bold")
    ax.set(xlabel="mission time [s]", title="Perception age of information per UAV")
    ax.legend(handles=[Patch(color="0.85", label="no neighbour held"), Patch(color="0.2", label="UAV lost"),
                       plt.Line2D([], [], marker="X", color="tab:red", ls="none", label="loss")],
              fontsize=8, loc="lower left", bbox_to_anchor=(0.0, 1.01), ncol=3, frameon=False, borderaxespad=0)
    ax.set_title("Perception age of information per UAV", pad=20)
    fig.tight_layout()
    return fig
