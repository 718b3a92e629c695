"""Live view (on a capture console), run summary and report plots."""

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
from rich.console import Console

from plmarl_sitl.sitl.live import SwarmView, UavView, headless_line, render, sparkline
from plmarl_sitl.sitl.summary import failure_recovery, summarize, timeliness, transient_label


def _view(**over):
    uavs = (
        UavView(id=0, mode="OFFBOARD", armed=True, pos_ned=(330.0, 300.0, -80.0), speed=3.2, neighbours=2, aoi_max=12.0, last_action=(0.5, -1.0, 0.0), link="ok"),
        UavView(id=1, alive=False, mode="HOLD", armed=False, pos_ned=(600.0, 330.0, -80.0), speed=0.0, link="lost"),
    )
    kw = dict(swarm="demo", t=101.0, coverage=0.812, coverage_history=(0.1, 0.5, 0.8, 0.9, 0.81), lambda2=2.97,
              messages_per_min=16.0, events_fired=("node_failure@100",), speedup=10.0, uavs=uavs)
    kw.update(over)
    return SwarmView(**kw)


def test_render_shows_every_field():
    console = Console(record=True, width=140)
    console.print(render(_view()))
    text = console.export_text()
    for needle in ["demo", "101.0", "0.812", "2.97", "16 msg/min", "node_failure@100", "OFFBOARD", "yes", "330", "80",
                   "3.2", "12", "+0.5 -1.0 +0.0", "ok", "dead"]:
        assert needle in text, needle
    assert sparkline((0.1, 0.5, 0.8, 0.9, 0.81)) in text


def test_render_fits_an_80_column_terminal():
    console = Console(record=True, width=80)
    console.print(render(_view()))
    lines = console.export_text().splitlines()
    assert max(len(x) for x in lines) <= 80
    assert not any("…" in x for x in lines), "\n".join(lines)  # nothing truncated
    assert any("OFFBOARD" in x and "+0.5 -1.0 +0.0" in x for x in lines)  # no truncation, no wrapping


def test_render_copes_with_unknowns():
    console = Console(record=True, width=140)
    console.print(render(_view(lambda2=math.nan, uavs=(UavView(id=3),), events_fired=())))
    text = console.export_text()
    assert "none yet" in text and "3" in text and "-" in text


def test_sparkline_scale():
    assert sparkline([0.0, 1.0]) == "▁█" and sparkline([float("nan"), 0.5]) == " ▅" and len(sparkline([0.5] * 99, width=40)) == 40


def test_headless_line():
    line = headless_line(_view())
    assert line.startswith("t= 101.0s coverage=0.812") and "alive=1/2" in line and "events=node_failure@100" in line


def test_failure_recovery_on_a_built_curve():
    """Coverage at 0.9 drops to 0.6 at t = 100 and climbs back to 0.88 (within the band
    max(0.02, 5 % of 0.9) = 0.045 of the pre-event 0.9) by t = 109: re-stabilised after 9 s."""
    t = np.arange(0, 200, dtype=float)
    c = np.full_like(t, 0.9)
    c[100:110] = np.linspace(0.6, 0.88, 10)
    c[110:] = 0.88
    r = failure_recovery(t, c, 100.0)
    assert r["trough"] == 0.6 and math.isclose(r["pre_event"], 0.9) and math.isclose(r["band"], 0.045)
    assert r["restabilize_s"] == 9.0 and r["end"] == 0.88 and math.isclose(r["plateau"], 0.88)
    assert transient_label(r).startswith("re-stabilised after 9 s (back within 0.045 of the pre-event 0.900, held >= 10 s")
    never = c.copy()
    never[-1] = 0.5  # falls out of the band at the very end: not recovered
    assert failure_recovery(t, never, 100.0)["restabilize_s"] is None


def test_a_new_lower_plateau_is_not_called_re_stabilised():
    """The issue's run: coverage 0.68 -> 0.58 and flat there. The old summary settled on the
    new plateau and said "re-stabilised after 70 s"; now it says it did not recover."""
    t = np.arange(0, 200, dtype=float)
    c = np.where(t < 100, 0.68, 0.58)
    c[100:105] = 0.5
    r = failure_recovery(t, c, 100.0)
    assert r["restabilize_s"] is None and r["settle_s"] == 5.0  # settled, at the lower level
    assert transient_label(r) == "did not recover (trough 0.500, end 0.580; pre-event 0.680)"


def test_recovery_must_hold_for_the_stated_time():
    """Back within the band only for the last 5 s of the run (< HOLD_S = 10 s): not yet
    recovered; back for 10 s: recovered. Above the pre-event level counts as recovered."""
    t = np.arange(0, 200, dtype=float)
    c = np.where(t < 100, 0.8, 0.6)
    c[-5:] = 0.79
    assert failure_recovery(t, c, 100.0)["restabilize_s"] is None
    c[-11:] = 0.95
    assert failure_recovery(t, c, 100.0)["restabilize_s"] == 89.0
    assert failure_recovery(t, c, 100.0, t_end=150.0)["restabilize_s"] is None  # the next failure came first
    assert "no data before" in transient_label(failure_recovery(t, c, 0.0))


def _rows(n=60):
    rows = []
    for k in range(n):
        cov = 0.9 if k < 30 else 0.7
        rows.append({"t": float(k), "coverage": cov, "lambda2": 3.0, "messages": 4, "uavs": [
            {"id": i, "alive": not (i == 1 and k >= 30), "pos_ned": [100.0 + k + 50 * i, 200.0, -80.0], "vel_ned": [1.0, 0.0, 0.0], "aoi_max": float(k % 15 + 1)}
            for i in range(3)]})
    return rows


def test_summarize_and_report_cli(tmp_path):
    rows = _rows()
    events = [{"t": 30.0, "type": "node_failure", "uav": 1}]
    summary = summarize(rows, events, speedup=10.0)
    assert math.isclose(summary["coverage_mean"], 0.8) and summary["coverage_min"] == 0.7 and summary["duration_s"] == 59.0
    fail = summary["node_failures"][0]
    assert fail["trough"] == 0.7 and fail["restabilize_s"] is None and fail["uav"] == 1
    assert fail["label"] == "did not recover (trough 0.700, end 0.700; pre-event 0.900)"
    (tmp_path / "metrics.jsonl").write_text("\n".join(json.dumps(r) for r in rows) + "\n")
    (tmp_path / "events.jsonl").write_text(json.dumps(events[0]) + "\n")
    old = {**summary, "node_failures": [{"at_s": 30.0, "trough": 0.7, "plateau": 0.7, "restabilize_s": 0.0}]}
    (tmp_path / "summary.json").write_text(json.dumps(old))  # a run recorded with the old, dishonest label
    r = subprocess.run([sys.executable, "-m", "plmarl_sitl.cli", "report", str(tmp_path), "--json", "--html"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["coverage_min"] == 0.7 and out["node_failures"][0]["label"].startswith("did not recover")
    for png in ("coverage.png", "aoi.png", "trajectories.png"):
        data = (tmp_path / png).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 5000
    lines = (tmp_path / "metrics.csv").read_text().splitlines()
    assert lines[0].startswith("t,coverage,lambda2,messages,alive,uav0_alive,uav0_north,uav0_east,uav0_alt,uav0_speed,uav0_aoi_max,")
    assert len(lines) == 61 and lines[31].split(",")[:5] == ["30", "0.7", "3", "4", "2"]
    assert lines[31].split(",")[5:11] == ["1", "130", "200", "80", "1", "1"]
    html = (tmp_path / "report.html").read_text()
    for png in ("coverage.png", "aoi.png", "trajectories.png"):
        assert f"alt='{png}' src='data:image/png;base64," in html
    assert "UAV 1 fails" in html and "did not recover (trough 0.700" in html and "<td>coverage mean</td>" in html


def test_trajectory_plot_shows_users_links_and_a_legend(tmp_path):
    """With the run's mission.yaml the plot has the users (t = 0 and the end), the U2U links of
    the last second (UAVs 0 and 2 are 100 m apart, UAV 1 is dead) and a legend naming them."""
    import shutil

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from plmarl_sitl.sitl.report_map import trajectory_figure

    shutil.copy(Path(__file__).resolve().parents[2] / "missions" / "paper_urban.yaml", tmp_path / "mission.yaml")
    fig = trajectory_figure(plt, tmp_path, _rows(), [{"t": 30.0, "type": "node_failure", "uav": 1}])
    ax = fig.axes[0]
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    texts = {t.get_text(): t.xy for t in ax.texts}
    launch = next(line for line in ax.get_lines() if str(line.get_label()).startswith("launch line"))
    tracks = {line.get_label(): line for line in ax.get_lines() if str(line.get_label()).startswith("UAV ")}
    plt.close(fig)
    assert labels == ["users at t = 0", "users at t = 59 s", "user cluster centres (4)", "launch line (4 slots, 40 m apart)",
                      "U2U links every 20 s (faded)", "U2U link (R_comm and SINR) at t = 59 s", "UAV 0", "UAV 1", "UAV 2",
                      "UAV at the end (its id beside it)", "lost UAV: where it stopped"]
    # the launch line of paper_urban: 4 slots 40 m apart, west to east, centred on (500, 470)
    assert list(launch.get_xdata()) == [410.0, 450.0, 490.0, 530.0] and set(launch.get_ydata()) == {500.0}
    # UAV 1 was alive up to t = 29 (north 100 + 29 + 50): its track ends there, marked and named
    assert texts["UAV 1 fails (t = 30 s)"] == (200.0, 179.0) and tracks["UAV 1"].get_ydata()[-1] == 179.0
    assert "UAV 0 fails" not in " ".join(texts) and texts["0"] == (200.0, 159.0)  # a live UAV: its id at its end
    fig = trajectory_figure(plt, tmp_path / "no-mission", _rows())  # an old run without mission.yaml: tracks only
    assert [t.get_text() for t in fig.axes[0].get_legend().get_texts()] == [
        "UAV 0", "UAV 1", "UAV 2", "UAV at the end (its id beside it)", "lost UAV: where it stopped"]
    plt.close(fig)


def test_trajectory_plot_draws_the_worlds_links_only(tmp_path):
    """The plotted links are `link_mask`'s on the live UAVs' 3-D positions: UAV 2 sits 30 m
    from UAV 0 and drowns UAV 1 (340 m away) at UAV 0's receiver, so 0 - 1 and 1 - 2 are heard
    one way only; 3 - 4 are 300 m apart on the ground but 360 m in 3-D (> R_comm = 350 m);
    dead UAV 5 neither links nor interferes. Pairs within R_comm on the ground alone would
    have drawn 0 - 1, 1 - 2 and 3 - 4 as links."""
    import shutil

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from plmarl_sitl.sitl.report_map import trajectory_figure

    shutil.copy(Path(__file__).resolve().parents[2] / "missions" / "paper_urban.yaml", tmp_path / "mission.yaml")
    pos = [[500.0, 500.0, -80.0], [500.0, 840.0, -80.0], [500.0, 530.0, -80.0], [900.0, 100.0, -80.0],
           [900.0, 400.0, -280.0], [500.0, 700.0, -80.0]]
    row = {"t": 7.0, "coverage": 0.5, "uavs": [{"id": i, "alive": i != 5, "pos_ned": p} for i, p in enumerate(pos)]}
    fig = trajectory_figure(plt, tmp_path, [row])
    ax = fig.axes[0]
    at = {(p[1], p[0]): i for i, p in enumerate(pos)}  # (east, north) -> UAV
    drawn = {}
    for line in ax.get_lines():
        if line.get_linestyle() in ("--", ":"):
            ends = sorted(at[(e, n)] for e, n in zip(line.get_xdata(), line.get_ydata(), strict=True))
            drawn[tuple(ends)] = line.get_linestyle()
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    plt.close(fig)
    assert drawn == {(0, 2): "--", (0, 1): ":", (1, 2): ":"}
    assert "U2U link (R_comm and SINR) at t = 7 s" in labels and "one-way U2U link at t = 7 s" in labels


def test_report_replays_the_users_of_the_run():
    """The plotted users are the world's and the twin's: same generator, stepped once a second."""
    import torch

    from plmarl_sitl.mission import load_mission
    from plmarl_sitl.sitl.report_map import replay_users
    from plmarl_sitl.twin.env import CoverageEnv

    for path in ("missions/paper_urban.yaml", "missions/suite/random_layout.yaml"):
        m = load_mission(Path(__file__).resolve().parents[2] / path)
        env = CoverageEnv(m, 1, 3)
        first, _ = replay_users(m, 3, 0)
        assert np.array_equal(first, env.users.xy[0].numpy())
        for _ in range(5):
            env.step(torch.zeros(1, m.n_uavs, 3))
        _, last = replay_users(m, 3, env.t)
        assert np.array_equal(last, env.users.xy[0].numpy())


def test_report_bad_input_is_one_line(tmp_path):
    (tmp_path / "metrics.jsonl").write_text('{"t": 0, "coverage": 0.5, "uavs": []}\n{not json\n')
    r = subprocess.run([sys.executable, "-m", "plmarl_sitl.cli", "report", str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "metrics.jsonl:2: not valid JSON" in r.stderr and "Traceback" not in r.stderr
    r = subprocess.run([sys.executable, "-m", "plmarl_sitl.cli", "report", str(tmp_path / "nope")], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "no such run directory" in r.stderr
    (tmp_path / "metrics.jsonl").write_text('{"t": 0, "coverage": 0.5, "uavs": []}\n')
    (tmp_path / "summary.json").write_text("{oops")
    r = subprocess.run([sys.executable, "-m", "plmarl_sitl.cli", "report", str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and "summary.json: not valid JSON" in r.stderr and "Traceback" not in r.stderr


def test_timeliness_counts_decisions_only():
    traces = [
        [{"t": 0, "boot_s": 30.5, "decided": True, "sense_t": None}, {"t": 1, "boot_s": 31.0, "decided": False, "sense_t": 0.0},
         {"t": 3, "boot_s": 33.1, "decided": True, "sense_t": 3.0}],
        [{"t": 3, "boot_s": 33.3, "decided": True, "sense_t": 1.0}, {"t": 6, "boot_s": 36.1, "decided": True, "sense_t": 6.0}],
    ]
    out = timeliness(traces, 30.0)
    assert out["decisions"] == 4
    assert out["decision_delay_s"]["max"] == 0.5 and out["decision_delay_s"]["p50"] == 0.2
    assert out["sensing_age_s"] == {"p50": 0.0, "p95": 1.8, "max": 2.0}
    assert timeliness([], None) == {"decisions": 0, "decision_delay_s": None, "sensing_age_s": None}


def test_monitor_reads_batched_deliveries_and_counts_bad_payloads():
    """What the live view shows of N_i comes from the link emulator's rx messages, which
    carry an instant's updates to one receiver back to back."""
    from plmarl_sitl.deploy.mqtt.schema import StateMsg, encode_json, encode_state
    from plmarl_sitl.sitl.monitor import SwarmMonitor

    mon = SwarmMonitor("sitl", tup_s=15, drop_after_missed=2)
    t = mon.topics

    def state(sender: int) -> bytes:
        return encode_state(StateMsg(sender, 1, 1, 15_000, (0.0, 0.0, -60.0, 0.0, 0.0, 0.0)))

    mon.on_bus(t.metrics, encode_json({"t": 20, "coverage": 0.5}))
    mon.on_bus(t.rx(0), state(1) + state(2))
    mon.on_bus(t.tx(1), state(1))
    assert mon.neighbours(0) == {1: 5.0, 2: 5.0} and mon.aoi_max(0) == 5.0
    assert mon.tx_total == 1 and mon.neighbours(1) == {}
    mon.on_bus(t.rx(1), state(0) + state(2)[:20])  # not whole messages: dropped whole
    assert mon.malformed == 1 and mon.neighbours(1) == {}


def test_a_uav_without_a_reported_position_is_recorded_and_plotted_without_one(tmp_path):
    """An external autopilot that is not streaming its local position has no pos/vel in the
    world's row (sitl/external.py::uav_rows): the metrics row records None, the plot leaves
    that second out of its track and the UAV out of the links, instead of failing the run."""
    import shutil

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from plmarl_sitl.sitl.monitor import SwarmMonitor
    from plmarl_sitl.sitl.report_map import trajectory_figure

    mon = SwarmMonitor("sitl", tup_s=15, drop_after_missed=2)
    mon.on_metrics({"t": 3, "coverage": 0.2, "lambda2": 0.0, "uav": [
        {"id": 0, "alive": True, "pos": [500.0, 500.0, -80.0], "vel": [0.0, 0.0, 0.0]},
        {"id": 1, "alive": True, "mode": "GUIDED", "armed": True, "acc": None},  # no local position yet
    ]})
    row = mon.metrics_row()
    assert row["uavs"][1]["pos_ned"] is None and row["uavs"][1]["vel_ned"] is None
    shutil.copy(Path(__file__).resolve().parents[2] / "missions" / "paper_urban.yaml", tmp_path / "mission.yaml")
    later = json.loads(json.dumps(row)) | {"t": 4}
    later["uavs"][1]["pos_ned"] = [500.0, 600.0, -80.0]
    fig = trajectory_figure(plt, tmp_path, [row, later])
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    plt.close(fig)
    assert "UAV 1" in labels and "U2U link (R_comm and SINR) at t = 4 s" in labels


# ---------------------------------------------------------------------- live map
def _map_view(n: int, lost: int | None = None):
    """A SwarmView with the map of a real mission (paper_urban at N = 4, scale_20 at N = 20):
    UAVs on their launch line spread north to south, the users replayed at t = 0."""
    from plmarl_sitl.mission import load_mission
    from plmarl_sitl.sitl.monitor import SwarmMonitor

    root = Path(__file__).resolve().parents[2] / "missions"
    mission = load_mission(root / ("paper_urban.yaml" if n == 4 else "scale_20.yaml"))
    assert mission.n_uavs == n
    mon = SwarmMonitor("sitl", 15, 2, mission=mission)
    uavs = [{"id": i, "alive": i != lost, "pos": [100.0 + 800.0 * i / (n - 1), 100.0 + 800.0 * i / (n - 1), -80.0],
             "vel": [0.0, 0.0, 0.0], "mode": "OFFBOARD", "armed": True} for i in range(n)]
    mon.on_metrics({"t": 5, "coverage": 0.5, "lambda2": 1.0, "uav": uavs})
    return mon.view(), mission


def test_live_map_at_n4_beside_the_table():
    """N = 4 on a wide terminal: the map sits beside the table, with every UAV's id, the lost
    UAV as a cross, the cluster centres, the users and the key. Neighbours on the diagonal
    are 377 m apart, beyond R_comm = 350 m: no links."""
    view, mission = _map_view(4, lost=2)
    console = Console(record=True, width=140, height=40, color_system=None)
    console.print(render(view))
    lines = console.export_text().splitlines()
    uav_row = next(x for x in lines if x.lstrip().startswith("0  OFFBOARD"))
    assert "│" in uav_row.split("OFFBOARD")[1]  # the map's frame on the table's first row: side by side
    text = "\n".join(lines)
    assert "✗2" in text and "+" in text and "░" in text and "0-9 UAV  ✗ lost  + cluster" in text
    for uid in ("0", "1", "3"):
        assert any(uid in x.split("│")[1] for x in lines if x.count("│") >= 2 and "┌" not in x), uid
    assert len(view.map.clusters) == 4 and view.map.links == ()  # 377 m apart in 3-D: beyond R_comm = 350 m
    assert max(len(x) for x in lines) <= 140


def test_live_map_at_n20_links_and_stacking():
    """N = 20: two-digit ids, the world's links drawn between linked UAVs; on an 80-column
    terminal the map goes below the table, and a terminal too short for it gets a note."""
    from plmarl_sitl.sitl.links import u2u_links
    from plmarl_sitl.sitl.live_map import MapUav, MapView, render_map

    view, mission = _map_view(20)
    assert len(view.map.links) > 0 and len(view.map.clusters) == 20 and len(view.map.users) == 1200
    console = Console(record=True, width=80, height=60, color_system=None)
    console.print(render(view))
    text = console.export_text()
    lines = text.splitlines()
    top = next(k for k, x in enumerate(lines) if x.startswith("┌"))
    assert top > next(k for k, x in enumerate(lines) if x.lstrip().startswith("19  OFFBOARD"))  # below the table
    assert "19" in "".join(lines[top:]) and "9─" in text and max(len(x) for x in lines) <= 80
    short = Console(record=True, width=80, height=24, color_system=None)
    short.print(render(view))
    assert "(map: a terminal" in short.export_text() and "┌" not in short.export_text()
    # the glyph of a link follows its slope; links come from the world's link_mask
    flat = MapView(1000, 1000, (MapUav(0, 500, 100), MapUav(1, 500, 900), MapUav(2, 100, 500)), links=((0, 1),))
    drawn = render_map(flat, 40).plain.splitlines()
    assert any("0" + "─" * 30 in x for x in drawn) and not any("╱" in x or "╲" in x for x in drawn)
    vee = (MapUav(0, 900, 100), MapUav(1, 900, 900), MapUav(2, 100, 500))  # 0 north-west, 1 north-east, 2 south
    slanted = render_map(MapView(1000, 1000, vee, links=((0, 2), (1, 2))), 40).plain
    assert "╲" in slanted and "╱" in slanted and "─" not in slanted.splitlines()[5]
    both, _ = u2u_links([{"id": i, "alive": True, "pos_ned": [500.0, 100.0 + 100 * i, -80.0]} for i in range(2)], mission)
    assert both == [(0, 1)]


# ---------------------------------------------------------------------- report figures
ALL_EVENTS = [
    {"t": 20.0, "type": "link_blackout", "duration_s": 10.0},
    {"t": 25.0, "type": "tup_change", "tup_s": 5},
    {"t": 30.0, "type": "node_failure", "uav": 1},
    {"t": 35.0, "type": "broker_outage", "duration_s": 5.0},
    {"t": 40.0, "type": "broker_outage_end"},
    {"t": 42.0, "type": "gnss_noise", "std_m": 3.0, "uavs": [0]},
    {"t": 45.0, "type": "gps_loss", "uavs": [2], "duration_s": 5.0},
    {"t": 48.0, "type": "motor_failure", "uav": 2},
    {"t": 48.5, "type": "autopilot", "uav": 2, "mode": "LAND"},
    {"t": 49.0, "type": "uav_failed", "uav": 2, "cause": "motor_failure"},
    {"t": 50.0, "type": "agent_failed", "uav": 0, "why": "owed an answer for 10 s"},
]


def test_every_event_type_is_named():
    from plmarl_sitl.sitl.report_events import event_label, lost_at, markers

    labels = [event_label(e) for e in ALL_EVENTS]
    assert labels[:4] == ["link blackout (all UAVs, 10 s)", "T_up -> 5 s", "UAV 1 fails", "broker outage (5 s)"]
    assert labels[5:8] == ["GNSS noise 3.0 m (UAV 0)", "GPS loss (UAV 2, 5 s)", "UAV 2 motor failure"]
    assert labels[8] == "UAV 2 autopilot: mode LAND" and labels[9] == "UAV 2 lost (motor failure)"
    assert labels[10] == "UAV 0's agent failed" and labels[4] == "broker outage ends"
    marks = markers(ALL_EVENTS, 60.0)
    assert [m.kind for m in marks] == ["link_blackout", "tup_change", "node_failure", "broker_outage", "gnss_noise",
                                       "gps_loss", "motor_failure", "uav_failed", "agent_failed"]
    windows = {m.kind: (m.t, m.end) for m in marks if m.end is not None}
    assert windows == {"link_blackout": (20.0, 30.0), "broker_outage": (35.0, 40.0), "gnss_noise": (42.0, 60.0),
                       "gps_loss": (45.0, 50.0)}
    assert lost_at(ALL_EVENTS) == {1: (30.0, "UAV 1 fails"), 2: (49.0, "UAV 2 lost (motor failure)"),
                                   0: (50.0, "UAV 0's agent failed")}


def test_coverage_figure_names_events_twin_and_transient():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from plmarl_sitl.sitl.report_plots import aoi_figure, coverage_figure

    rows = _rows()
    summary = summarize(rows, [ALL_EVENTS[2]], speedup=10.0)
    twin = {"coverage": [0.9] * 29 + [0.69] * 40, "label": "twin: same mission, seed 0, policy pl-marl"}
    fig = coverage_figure(plt, rows, ALL_EVENTS, summary, twin)
    ax, ax2 = fig.axes
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    texts = [t.get_text() for t in ax.texts]
    notes = [t.get_text() for t in fig.texts]
    plt.close(fig)
    assert legend[0] == "SITL run (mean 0.800)" and legend[1].startswith("twin: same mission, seed 0, policy pl-marl (mean ")
    assert legend[2] == "recovery band: pre-event level +- band"
    for name in ("link blackout (all UAVs, 10 s)", "T_up -> 5 s", "UAV 1 fails", "broker outage (5 s)", "GNSS noise 3.0 m (UAV 0)",
                 "GPS loss (UAV 2, 5 s)", "UAV 2 motor failure", "UAV 2 lost (motor failure)", "UAV 0's agent failed"):
        assert name in texts, name
    assert ax2.get_ylabel() == "lambda_2"
    assert any("UAV 1 at 30 s: did not recover (trough 0.700, end 0.700; pre-event 0.900)" in n for n in notes)
    fig = aoi_figure(plt, rows, [ALL_EVENTS[2]], horizon_s=30)
    ax = fig.axes[0]
    images = ax.get_images()
    heat = images[-1].get_array()
    plt.close(fig)
    assert heat.shape == (3, 60) and heat.mask[1, 30:].all() and not heat.mask[0].any()  # UAV 1 lost from t = 30
    assert "UAV 1 fails" in [t.get_text() for t in ax.texts] and [t.get_text() for t in ax.get_yticklabels()] == [
        "UAV 0", "UAV 1", "UAV 2"]


def test_report_draws_the_twins_run_of_the_same_mission_seed_and_policy(tmp_path):
    """With the run's mission.yaml, seed and policy, `plmarl report` flies the same policy in
    the twin, labels the line as such, and caches it; a second report reuses the cache."""
    root = Path(__file__).resolve().parents[2]
    (tmp_path / "mission.yaml").write_text(f"extends: {root / 'missions' / 'node_failure.yaml'}\nname: short\n"
                                           "timing: {dt_s: 1, decision_every_s: 3, episode_s: 20}\n"
                                           "events:\n  - {type: node_failure, at_s: 10, uav: 2}\n")
    rows = [{"t": float(k), "coverage": 0.5, "lambda2": 1.0, "messages": 0,
             "uavs": [{"id": i, "alive": not (i == 2 and k >= 10), "pos_ned": [500.0, 410.0 + 40 * i, -60.0],
                       "vel_ned": [0.0, 0.0, 0.0], "aoi_max": None} for i in range(4)]} for k in range(21)]
    (tmp_path / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    (tmp_path / "events.jsonl").write_text(json.dumps({"t": 10.0, "type": "node_failure", "uav": 2}) + "\n")
    (tmp_path / "summary.json").write_text(json.dumps({**summarize(rows, [], 10.0), "seed": 3,
                                                       "policy": str(root / "policies" / "pl-marl")}))
    cmd = [sys.executable, "-m", "plmarl_sitl.cli", "report", str(tmp_path)]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "reference: twin: same mission, seed 3, policy pl-marl: mean coverage" in r.stdout
    cache = json.loads((tmp_path / "twin_coverage.json").read_text())
    assert cache["key"]["seed"] == 3 and len(cache["coverage"]) == 20 and all(0 <= c <= 1 for c in cache["coverage"])
    stamp = (tmp_path / "twin_coverage.json").stat().st_mtime_ns
    from plmarl_sitl.cli.report import twin_reference

    summary = json.loads((tmp_path / "summary.json").read_text())
    again = twin_reference(tmp_path, summary, None, [])
    assert again["coverage"] == cache["coverage"] and (tmp_path / "twin_coverage.json").stat().st_mtime_ns == stamp
    notes = []
    assert twin_reference(tmp_path / "elsewhere", summary, None, notes) is None
    assert notes == ["no twin reference: the run directory has no mission.yaml"]


def test_report_help_states_the_rule_and_its_outputs():
    r = subprocess.run([sys.executable, "-m", "plmarl_sitl.cli", "report", "--help"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and "%%" not in r.stdout
    for needle in ("max(0.02, 5 %)", "metrics.csv", "--html", "--no-twin", "twin"):
        assert needle in r.stdout, needle


def test_the_view_names_events_and_the_headless_line_keeps_their_type():
    from plmarl_sitl.sitl.monitor import SwarmMonitor

    mon = SwarmMonitor("sitl", tup_s=15, drop_after_missed=2)
    mon.on_metrics({"t": 101, "coverage": 0.7, "lambda2": 0.0, "uav": [{"id": 2, "alive": False, "pos": [1.0, 2.0, 0.0]}]})
    mon.on_event({"t": 100.0, "type": "node_failure", "uav": 2})
    mon.on_event({"t": 101.0, "type": "link_blackout", "duration_s": 30.0})
    view = mon.view()
    console = Console(record=True, width=120)
    console.print(render(view))
    assert "UAV 2 fails at 100 s, link blackout (all UAVs, 30 s) at 101 s" in console.export_text()
    assert "events=node_failure@100,link_blackout@101" in headless_line(view)
