"""The reach warning (clusters more than R_comm apart) is for a user's mission; the project's
suite, whose thin_area_b has its relay gap on purpose, loads without it."""

import logging

from plmarl_sitl.config import PROJECT_SUITE
from plmarl_sitl.learning.eval.suite import load_suite
from plmarl_sitl.mission import load_mission

GAPPED = PROJECT_SUITE.parent / "thin_area_b.yaml"


def test_a_gapped_mission_warns_and_the_projects_suite_does_not(caplog):
    with caplog.at_level(logging.WARNING, logger="plmarl.mission"):
        load_mission(GAPPED)
    assert any("cannot stay connected" in r.getMessage() for r in caplog.records)
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="plmarl.mission"):
        load_mission(GAPPED, warn=False)
        load_suite(PROJECT_SUITE)
    assert not caplog.records
