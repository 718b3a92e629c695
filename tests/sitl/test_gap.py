"""`python -m plmarl_sitl.bench.gap`: the twin and lockstep SITL on one short mission, run the
way RESULTS runs it but from outside the checkout (its defaults are the project's files), and
its user errors (one line, exit 2)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _gap(cwd: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "plmarl_sitl.bench.gap", *args], capture_output=True, text=True,
                          timeout=300, cwd=cwd)


def test_lockstep_gap_on_a_short_mission_from_any_directory(tmp_path: Path) -> None:
    (tmp_path / "short.yaml").write_text(f"extends: {ROOT / 'missions' / 'paper_urban.yaml'}\nname: short_gap\n"
                                         "timing: {episode_s: 20}\n")
    r = _gap(tmp_path, "short.yaml", "--seeds", "3", "--lockstep", "--json")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["policy"] == str(ROOT / "policies" / "pl-marl")
    assert out["per_seed"][0]["sitl_seconds"] == 20
    assert 0.3 < out["twin_mean"] < 1.0 and abs(out["gap"]) <= 0.01


def test_user_errors_are_one_line_and_exit_2(tmp_path: Path) -> None:
    for args, says in ((["nosuch.yaml"], "cannot read file"),
                       ([str(ROOT / "missions" / "paper_urban.yaml"), "--policy", str(tmp_path / "none")],
                        "missing policy directory"),
                      ([str(ROOT / "missions" / "paper_urban.yaml"), "--start-wall-s", "0"], "--start-wall-s must be > 0")):
        r = _gap(tmp_path, *args)
        assert r.returncode == 2 and says in r.stderr and r.stderr.strip().count("\n") == 0, r.stderr


def test_a_bad_seed_is_argparse_s_one_error_line(tmp_path: Path) -> None:
    r = _gap(tmp_path, str(ROOT / "missions" / "paper_urban.yaml"), "--seeds", "0", "-1")
    assert r.returncode == 2 and "seed -1 is outside" in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert sum("error:" in line for line in r.stderr.splitlines()) == 1, r.stderr
