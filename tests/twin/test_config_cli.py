"""Mission YAML errors name their path; the CLI turns them into one line and exit 2."""

import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from plmarl_sitl.config import ConfigError
from plmarl_sitl.mission import load_mission

BASE = yaml.safe_load(Path("missions/paper_urban.yaml").read_text())


def _write(tmp_path, data):
    p = tmp_path / "m.yaml"
    p.write_text(yaml.safe_dump(data))
    return p


def _with(path_keys, value):
    data = yaml.safe_load(yaml.safe_dump(BASE))
    node = data
    for k in path_keys[:-1]:
        node = node[k]
    node[path_keys[-1]] = value
    return data


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        ((["users", "clusters"], 4), "users.clusters: unknown key"),
        ((["failures"], [{"at_s": "soon", "uav": 1}]), "failures[0].at_s: expected a number"),
        ((["failures"], [{"at_s": -1, "uav": 1}]), "failures[0].at_s: must be >= 0"),
        ((["failures"], [{"at_s": 10, "uav": 4}]), "failures[0].uav: must be < n_uavs (4)"),
        ((["failures"], [{"uav": 1}]), "failures[0].at_s: is required"),
        ((["signalling", "tup_s"], 2.5), "signalling.tup_s: expected an integer"),
        ((["users", "mobility"], "teleport"), "users.mobility: expected one of"),
        ((["users", "cluster_centers"], [[1, 2]]), "users.cluster_centers: layout 'fixed' needs 4 centres"),
        ((["radii"], "big"), "radii: expected a mapping"),
        ((["demand"], {"cell_m": 2}), "demand.cell_m: too small for the area: 250000 cells"),
        ((["launch", "bearing_deg"], 400), "launch.bearing_deg: must be <= 360"),
    ],
)
def test_errors_name_the_path(tmp_path, edit, message):
    with pytest.raises(ConfigError) as exc:
        load_mission(_write(tmp_path, _with(*edit)))
    assert message in str(exc.value)
    assert str(tmp_path / "m.yaml") in str(exc.value)


def test_shipped_mission_loads():
    m = load_mission("missions/paper_urban.yaml")
    assert (m.n_uavs, m.users.count, m.radii.comm_m, m.signalling.tup_s) == (4, 240, 350.0, 15)
    assert m.reward.post_failure.potential == 2.0 and m.reward.pre_failure.mobility == 2e-5


def _plmarl(*args):
    return subprocess.run([sys.executable, "-m", "plmarl_sitl.cli", *args], capture_output=True, text=True, timeout=300)


def test_cli_bad_yaml_is_one_line_exit_2(tmp_path):
    bad = _write(tmp_path, _with(["failures"], [{"at_s": "soon", "uav": 1}]))
    r = _plmarl("sim", str(bad), "--episodes", "1")
    assert r.returncode == 2
    assert "Traceback" not in r.stderr
    assert r.stderr.strip().count("\n") == 0 and "failures[0].at_s: expected a number" in r.stderr


def test_cli_missing_file_exit_2():
    r = _plmarl("sim", "no/such/mission.yaml")
    assert r.returncode == 2 and "cannot read file" in r.stderr and "Traceback" not in r.stderr


def test_cli_sim_json_is_one_object_and_deterministic():
    runs = [_plmarl("sim", "missions/paper_urban.yaml", "--method", "heuristic", "--episodes", "3", "--seed", "5", "--json", "--tup", "10") for _ in range(2)]
    for r in runs:
        assert r.returncode == 0, r.stderr
    outs = [json.loads(r.stdout) for r in runs]
    assert outs[0] == outs[1]
    assert set(outs[0]) == {"coverage_mean", "coverage_ci95", "lambda2_mean", "min_separation_m", "method", "episodes", "seed"}
    assert outs[0]["method"] == "heuristic"
    lo, hi = outs[0]["coverage_ci95"]
    assert lo <= outs[0]["coverage_mean"] <= hi and outs[0]["seed"] == 5 and outs[0]["episodes"] == 3


def test_extends_merges_and_overrides(tmp_path):
    base = _write(tmp_path, BASE)
    child = tmp_path / "child.yaml"
    child.write_text(f"extends: {base.name}\nname: child\nradii: {{comm_m: 300}}\nevents: [{{type: tup_change, at_s: 5, tup_s: 30}}]\n")
    m = load_mission(child)
    assert m.name == "child" and m.radii.comm_m == 300.0 and m.radii.sensing_m == 100.0
    assert m.events[0].tup_s == 30 and m.users.count == 240


def test_extends_cycle_and_errors_name_the_child(tmp_path):
    a, b = tmp_path / "a.yaml", tmp_path / "b.yaml"
    a.write_text("extends: b.yaml\nname: a\n")
    b.write_text("extends: a.yaml\nname: b\n")
    with pytest.raises(ConfigError, match="cycle"):
        load_mission(a)
    c = tmp_path / "c.yaml"
    c.write_text("extends: ../../no/such.yaml\nname: c\n")
    with pytest.raises(ConfigError, match="extends: no mission file") as exc:
        load_mission(c)
    assert str(exc.value).startswith(str(c))


@pytest.mark.parametrize(
    ("event", "message"),
    [
        ({"type": "link_blackout", "at_s": 5}, "events[0].duration_s: is required for a link_blackout event"),
        ({"type": "tup_change", "at_s": 5, "tup_s": 10, "uav": 1}, "events[0].uav: not used by a tup_change event"),
        ({"type": "node_failure", "at_s": 5, "uav": 7}, "events[0].uav: must be < n_uavs (4)"),
        ({"type": "gnss_noise", "at_s": -2, "std_m": 1}, "events[0].at_s: must be >= 0"),
        ({"type": "meteor", "at_s": 5}, "events[0].type: expected one of"),
    ],
)
def test_event_errors_name_the_path(tmp_path, event, message):
    with pytest.raises(ConfigError) as exc:
        load_mission(_write(tmp_path, _with(["events"], [event])))
    assert message in str(exc.value)


@pytest.mark.parametrize("name", ["paper_urban", "node_failure", "blackout", "broker_outage", "scale_20"])
def test_shipped_missions_load(name):
    m = load_mission(f"missions/{name}.yaml")
    assert m.name == name and m.users.count == 60 * m.n_uavs
