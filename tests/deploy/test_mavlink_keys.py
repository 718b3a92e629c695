"""MAVLink signing keys at start: a missing, unreadable, exposed or wrong-size key is one
line on stderr and exit code 2 before anything starts, never an unsigned link."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from plmarl_sitl.deploy.mavlink.keys import create_key_files, load_key_files

ROOT = Path(__file__).resolve().parents[2]
AGENT = ["agent", "--id", "0", "--connect", "udpout://127.0.0.1:1", "--broker", "mqtt://127.0.0.1:1", "--no-auth"]


def _write(path: Path, text: str, mode: int = 0o600) -> Path:
    path.write_text(text)
    os.chmod(path, mode)
    return path


def _cli(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "plmarl_sitl.cli", *argv], capture_output=True, text=True, cwd=ROOT,
                          timeout=120, env=dict(os.environ, PYTHONPATH=str(ROOT)))


@pytest.mark.parametrize("case,needle", [
    ("missing", "--mavlink-key {p}: cannot read the key file"),
    ("short", "--mavlink-key {p}: not a key file (64 hexadecimal characters expected)"),
    ("long", "--mavlink-key {p}: not a key file (64 hexadecimal characters expected)"),
    ("exposed", "--mavlink-key {p}: the key file is accessible to others (mode 644)"),
    ("directory", "--mavlink-key {p}: cannot read the key file"),
])
def test_agent_key_errors_are_one_line(tmp_path: Path, case: str, needle: str) -> None:
    p = tmp_path / "vehicle0.key"
    if case == "short":
        _write(p, "ab" * 16 + "\n")
    elif case == "long":
        _write(p, "ab" * 33 + "\n")
    elif case == "exposed":
        _write(p, "ab" * 32 + "\n", 0o644)
    elif case == "directory":
        p.mkdir()
    r = _cli(*AGENT, "--mavlink-key", str(p))
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and needle.format(p=p) in lines[0], r.stderr


def test_swarm_up_and_world_key_directory_errors(tmp_path: Path) -> None:
    keys = tmp_path / "keys"
    create_key_files(keys, 4)
    (keys / "vehicle2.key").unlink()
    r = _cli("swarm", "up", "missions/paper_urban.yaml", "--mavlink-keys", str(keys), "--out", str(tmp_path / "run"))
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1
    assert f"--mavlink-keys {keys / 'vehicle2.key'}: cannot read the key file" in r.stderr
    assert not (tmp_path / "run").exists(), "nothing may start before the keys are checked"
    r = _cli("world", "missions/paper_urban.yaml", "--broker", "mqtt://127.0.0.1:1", "--no-auth", "--mavlink-keys", str(keys))
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "vehicle2.key" in r.stderr
    r = _cli("swarm", "up", "missions/paper_urban.yaml", "--mavlink-keys", str(keys), "--no-mavlink-sign")
    assert r.returncode == 2 and "choose one" in r.stderr


def test_key_files_are_private_and_distinct(tmp_path: Path) -> None:
    keys = create_key_files(tmp_path / "k", 3)
    assert load_key_files(tmp_path / "k", 3, "--mavlink-keys") == keys and len(set(keys)) == 3
    assert all(len(k) == 32 for k in keys)
    assert oct((tmp_path / "k").stat().st_mode & 0o777) == "0o700"
    assert all(oct(p.stat().st_mode & 0o777) == "0o600" for p in (tmp_path / "k").iterdir())
