"""`plmarl bench infer`: every policy file called with the inputs of its version, and the team plan timed."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from plmarl_sitl.bench import infer
from plmarl_sitl.errors import UserError

ROOT = Path(__file__).resolve().parents[2]


def test_methods_are_names_or_label_dir_pairs(tmp_path: Path) -> None:
    old = tmp_path / "runs" / "x" / "pl-marl"
    old.mkdir(parents=True)
    got = infer.parse_methods(f"pl-marl, old={old}", Path("policies"))
    assert got == {"pl-marl": ("pl-marl", Path("policies/pl-marl")), "old": ("old", old)}
    for bad in ("old=", "=runs/x"):
        with pytest.raises(UserError, match="give LABEL=DIR"):
            infer.parse_methods(bad, Path("policies"))


def test_a_missing_label_dir_is_one_line_and_exit_2(tmp_path: Path) -> None:
    """LABEL=DIR with no such DIR is a user error, not untrained modules timed under LABEL; a
    bare NAME without <--policies>/NAME/card.yaml still times untrained modules."""
    import subprocess
    import sys

    missing = tmp_path / "no-such-run" / "pl-marl"
    r = subprocess.run([sys.executable, "-m", "plmarl_sitl.cli", "bench", "infer", "--n", "4", "--calls", "5",
                        "--methods", f"old={missing}"], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert r.returncode == 2
    assert r.stderr.splitlines() == [f"plmarl bench: error: --methods old={missing}: no such directory {missing}"]
    assert r.stdout == ""
    r = subprocess.run([sys.executable, "-m", "plmarl_sitl.cli", "bench", "infer", "--n", "4", "--calls", "5", "--json",
                        "--methods", "pl-marl", "--policies", str(tmp_path)], capture_output=True, text=True, timeout=120,
                       cwd=ROOT)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["weights"] == {"pl-marl": "untrained"}


def test_team_plan_inputs_are_a_twin_instant() -> None:
    pi = infer.plan_inputs(6, 0)
    assert pi.mission.n_uavs == 6 and pi.mission.users.count == 360
    assert pi.decisions_per_map == 10  # a map every 30 s, a decision every 3 s
    assert len(pi.maps) == 2 and all((m[:, 2] > 0).all() for m in pi.maps)  # wire form: nonzero cells
    assert pi.held.shape == (6, 6) and pi.t_rx.shape == (6,)


@pytest.mark.parametrize("shipped", ["policies/wave1/pl-marl", "policies/pl-marl"])
def test_plan_rows_and_versions(tmp_path: Path, shipped: str) -> None:
    """A plan-taking file (untrained here) and a shipped one (any input version) run side by side."""
    if not (ROOT / shipped / "card.yaml").is_file():
        pytest.skip(f"{shipped} is not in this checkout")
    (tmp_path / "none").mkdir()  # a directory without card.yaml
    args = argparse.Namespace(n=[4], methods=f"untrained={tmp_path / 'none'},shipped={ROOT / shipped}",
                              policies="policies", calls=12, seed=0)
    res = infer.run(args)
    rows = {r["method"]: r for r in res["rows"]}
    assert res["weights"] == {"untrained": "untrained", "shipped": "trained"}
    for dec, new_map, amort, _ in infer.COORDINATIONS.values():  # the team plan and the local plan
        assert {"untrained", "shipped", dec, new_map, amort} <= set(rows)
        assert rows[dec]["calls"] == 10 and rows[new_map]["calls"] == 2  # every 10th decision brings a new map
        want = (9 * rows[dec]["median_us"] + rows[new_map]["median_us"]) / 10
        assert rows[amort]["median_us"] == pytest.approx(want)
        assert rows[amort]["decisions_per_map"] == 10


def test_the_defaults_time_the_shipped_files_from_any_directory(tmp_path: Path) -> None:
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "plmarl_sitl.cli", "bench", "infer", "--n", "4", "--calls", "5", "--json"],
                       capture_output=True, text=True, timeout=180, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["weights"] == {"pl-marl": "trained", "gru": "trained", "pl-marl-wave1": "trained"}
    assert out["dirs"]["pl-marl-wave1"] == str(ROOT / "policies" / "wave1" / "pl-marl")


def test_area_and_the_decision_including_the_plan(tmp_path: Path) -> None:
    """--area puts the plan's map (and the neighbours) on a square of that side; each method
    that takes the plan gets a row with its decision plus the amortised plan."""
    shipped = ROOT / "policies" / "pl-marl"
    if not (shipped / "card.yaml").is_file():
        pytest.skip("policies/pl-marl is not in this checkout")
    pi = infer.plan_inputs(4, 0, 3000.0)
    assert (pi.mission.area.north_m, pi.mission.area.east_m) == (3000.0, 3000.0)
    assert pi.mission.launch.north_m == 1500.0 and pi.maps[0][:, 0].min() > 1000.0  # the lattice in the middle
    args = argparse.Namespace(n=[4], methods=f"shipped={shipped}", policies="policies", calls=12, seed=0, area=3000.0)
    res = infer.run(args)
    rows = {r["method"]: r for r in res["rows"]}
    assert res["area_m"] == 3000.0
    with_plan = rows["shipped" + infer.WITH_PLAN]
    assert with_plan["median_us"] == pytest.approx(rows["shipped"]["median_us"] + rows[infer.PLAN_AMORTISED]["median_us"])
    assert with_plan["cpu_median_us"] == pytest.approx(rows["shipped"]["cpu_median_us"] + rows[infer.PLAN_AMORTISED]["cpu_median_us"])
    with_local = rows["shipped" + infer.WITH_LOCAL]  # the neighbourhood plan (coordination: local) the same way
    assert with_local["cpu_median_us"] == pytest.approx(rows["shipped"]["cpu_median_us"] + rows[infer.LOCAL_AMORTISED]["cpu_median_us"])
    assert 0 < rows[infer.PLAN_MAP]["cpu_median_us"] <= rows[infer.PLAN_MAP]["median_us"] * 1.05  # CPU time never exceeds wall time


@pytest.mark.parametrize("bad", ["50", "x", "inf", "-3000"])
def test_a_bad_area_is_one_line_and_exit_2(bad: str) -> None:
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "plmarl_sitl.cli", "bench", "infer", "--n", "4", "--calls", "5",
                        "--area", bad], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert r.returncode == 2
    assert r.stderr.strip().splitlines()[-1].endswith(f"argument --area: {bad!r} is not a side of at least 100 m")
    assert "Traceback" not in r.stderr


def test_placement_option_sets_the_plan_placement_and_a_wrong_one_is_one_line() -> None:
    """`--placement greedy` times the greedy at every N (the mission default is the search up to
    20 points); the placement reaches the team plan's mission and the JSON says which it was."""
    import subprocess
    import sys

    assert infer.plan_inputs(6, 0).mission.placement == "search"
    assert infer.plan_inputs(6, 0, placement="greedy").mission.placement == "greedy"
    r = subprocess.run([sys.executable, "-m", "plmarl_sitl.cli", "bench", "infer", "--n", "4", "--calls", "3", "--json",
                        "--methods", "pl-marl", "--placement", "greedy"], capture_output=True, text=True, timeout=300,
                       cwd=ROOT)
    assert r.returncode == 0, r.stderr
    res = json.loads(r.stdout)
    assert res["placement"] == "greedy"
    assert {row["method"] for row in res["rows"]} >= {infer.PLAN_MAP, infer.PLAN_DECISION}
    r = subprocess.run([sys.executable, "-m", "plmarl_sitl.cli", "bench", "infer", "--placement", "best"],
                       capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert r.returncode == 2 and "--placement: invalid choice: 'best'" in r.stderr and "Traceback" not in r.stderr
