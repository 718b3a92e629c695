"""`python -m plmarl_sitl.bench.fig5`: Fig. 5a/5b (C(t), lambda_2(t)) of a failure mission, twin
beside lockstep SITL, on a shortened failure-in-transit mission; and its user errors."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _fig5(cwd: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "plmarl_sitl.bench.fig5", *args], capture_output=True, text=True,
                          timeout=300, cwd=cwd)


def test_failure_transient_and_lambda2_twin_beside_sitl(tmp_path: Path) -> None:
    (tmp_path / "short.yaml").write_text(f"extends: {ROOT / 'missions' / 'suite' / 'failure_transit.yaml'}\n"
                                         "name: short_transit\ntiming: {episode_s: 45}\n")
    r = _fig5(tmp_path, "short.yaml", "--seed", "1", "--out", "fig")
    assert r.returncode == 0, r.stderr
    (row,) = json.loads((tmp_path / "fig" / "fig5.json").read_text())
    assert row["failures_s"] == [30]  # the family's own failure, marked on the figure
    for side in ("twin", "sitl"):
        assert len(row[side]["coverage"]) == 45 and len(row[side]["lambda2"]) == 45, side
    # the failed UAV leaves the graph: lambda_2 changes at the failure on both sides
    assert row["twin"]["lambda2"][28] != row["twin"]["lambda2"][31]
    assert abs(row["gap"]) <= 0.01  # lockstep: the SITL curve lies on the twin's
    assert (tmp_path / "fig" / "fig5.png").stat().st_size > 10_000


def test_a_missing_mission_is_one_line_and_exit_2(tmp_path: Path) -> None:
    r = _fig5(tmp_path, "nosuch.yaml")
    assert r.returncode == 2 and "no mission file nosuch.yaml" in r.stderr and r.stderr.strip().count("\n") == 0, r.stderr
