"""`plmarl swarm up` with MAVLink signing (on by default): the mission completes signed.

Every vehicle and its agent share a fresh key (RUN/mavlink/vehicleI.key, 0600); every
frame on every vehicle's link, both ways, is signed; no vehicle dropped any input.
"""

import json
import stat
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = [pytest.mark.integration, pytest.mark.slow]
ROOT = Path(__file__).resolve().parents[2]
SIGNED = 0x01  # MAVLINK_IFLAG_SIGNED in a MAVLink 2 frame's incompat flags


def _frames(tlog: Path) -> list[bytes]:
    """The MAVLink 2 frames of a .tlog (8-byte timestamp, frame)."""
    data = tlog.read_bytes()
    out, i = [], 0
    while i + 10 < len(data):
        start = i + 8
        assert data[start] == 0xFD, "the emulator speaks MAVLink 2 only"
        length = 12 + data[start + 1] + (13 if data[start + 2] & SIGNED else 0)
        out.append(data[start:start + length])
        i = start + length
    return out


def test_mission_completes_signed(tmp_path):
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "plmarl_sitl.cli", "swarm", "up", str(ROOT / "missions" / "paper_urban.yaml"),
           "--speedup", "10", "--duration", "40", "--out", str(out), "--json"]
    r = subprocess.run(cmd, capture_output=True, text=True, timeout=240, cwd=ROOT)
    assert r.returncode == 0, r.stderr[-2000:]
    s = json.loads(r.stdout.strip().splitlines()[-1])
    assert s["mavlink_signed"] and s["coverage_mean"] > 0.4
    keys = sorted((out / "mavlink").iterdir())
    assert [k.name for k in keys] == [f"vehicle{i}.key" for i in range(4)]
    assert stat.S_IMODE((out / "mavlink").stat().st_mode) == 0o700
    assert all(stat.S_IMODE(k.stat().st_mode) == 0o600 for k in keys)
    assert len({k.read_text() for k in keys}) == 4, "a key per vehicle"
    for i, counters in enumerate(s["vehicle_input"]):
        assert counters["unsigned"] == counters["bad_signature"] == 0, (i, counters)
        frames = _frames(out / "tlogs" / f"vehicle{i}.tlog")
        agent = [f for f in frames if f[5] == 255]  # sysid 255: the agent's frames, as received
        assert len(agent) > 100 and all(f[2] & SIGNED for f in frames), f"vehicle {i}: an unsigned frame"
