"""docs/MISSIONS.md is generated from the schema and current; loading warns about clusters out of reach."""

import logging
from pathlib import Path

import yaml

from plmarl_sitl import mission_reference
from plmarl_sitl.mission import load_mission

ROOT = Path(__file__).resolve().parent.parent


def test_reference_is_current():
    assert mission_reference.main(["--check"]) == 0, "run: python -m plmarl_sitl.mission_reference"


def test_every_key_is_in_the_reference():
    text = mission_reference.render()
    for key in ("`n_uavs`", "`launch.bearing_deg`", "`events[].duration_s`", "`reward.*.safety`", "`max_climb_mps`"):
        assert key in text
    assert "4294967295" in text and "<= 250" in text  # bounds come from the schema's metadata


def test_unreachable_clusters_warn(tmp_path, caplog):
    data = yaml.safe_load((ROOT / "missions/paper_urban.yaml").read_text())
    data["area"] = {"north_m": 1500, "east_m": 1500}
    data["users"]["cluster_centers"] = [[330, 300], [600, 330], [680, 610], [1400, 1400]]  # the last is ~1000 m out
    p = tmp_path / "m.yaml"
    p.write_text(yaml.safe_dump(data))
    with caplog.at_level(logging.WARNING, logger="plmarl.mission"):
        load_mission(p)
    assert any("2 groups more than R_comm (350 m) apart (0, 1, 2; 3)" in r.getMessage() for r in caplog.records)


def test_shipped_missions_do_not_warn(caplog):
    with caplog.at_level(logging.WARNING, logger="plmarl.mission"):
        for m in sorted((ROOT / "missions").glob("*.yaml")):
            load_mission(m)
    assert not caplog.records, [r.getMessage() for r in caplog.records]
