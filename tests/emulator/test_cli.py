"""`plmarl autopilot` as a user runs it: a real process, a real client, Ctrl-C."""

from __future__ import annotations

import random
import signal
import socket
import subprocess
import sys
import time

import pytest
from pymavlink import mavutil

pytestmark = [pytest.mark.integration, pytest.mark.timeout(60)]


def _free_udp_port() -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    return s


def test_cli_serves_vehicles_pushes_to_gcs_and_exits_cleanly_on_ctrl_c() -> None:
    gcs = _free_udp_port()
    gcs.settimeout(5)
    base = random.randrange(20000, 60000)
    proc = subprocess.Popen(
        [sys.executable, "-m", "plmarl_sitl.cli", "autopilot", "--count", "2", "--base-port", str(base),
         "--personality", "ardupilot", "--speedup", "5", "--gcs", f"udp:127.0.0.1:{gcs.getsockname()[1]}"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        line = proc.stdout.readline()
        assert "Ctrl-C stops" in line, line + proc.stderr.read()
        # The ground station only listens; both vehicles push heartbeats to it.
        parser = mavutil.mavlink.MAVLink(None)
        seen: set[int] = set()
        deadline = time.monotonic() + 5
        while seen != {1, 2} and time.monotonic() < deadline:
            data = gcs.recv(4096)
            for m in parser.parse_buffer(data) or []:
                if m.get_type() == "HEARTBEAT":
                    seen.add(m.get_srcSystem())
        assert seen == {1, 2}

        m = mavutil.mavlink_connection(f"udpout:127.0.0.1:{base + 1}", source_system=255)
        m.mav.heartbeat_send(6, 8, 0, 0, 0)
        assert m.wait_heartbeat(timeout=5) is not None and m.target_system == 2
        lpn = m.recv_match(type="LOCAL_POSITION_NED", blocking=True, timeout=5)
        assert lpn is not None
        m.close()
    finally:
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=10)
        gcs.close()
    assert proc.returncode == 0, err
    assert "Traceback" not in err and "stopped after" in err


def test_cli_rejects_bad_flags_without_traceback() -> None:
    r = subprocess.run(
        [sys.executable, "-m", "plmarl_sitl.cli", "autopilot", "--signing-key", "abc"],
        capture_output=True, text=True, timeout=30,
    )
    assert r.returncode == 2 and "signing-key" in r.stderr and "Traceback" not in r.stderr


def test_cli_rejects_an_unknown_autopilot_in_one_line() -> None:
    r = subprocess.run(
        [sys.executable, "-m", "plmarl_sitl.cli", "autopilot", "--personality", "betaflight"],
        capture_output=True, text=True, timeout=30,
    )
    assert r.returncode == 2 and r.stdout == ""
    assert r.stderr == "plmarl autopilot: error: unknown autopilot 'betaflight' (known: px4, ardupilot)\n"
