"""The two targets of the differential suite, started the same way a user starts them.

`emulator`: `plmarl autopilot --personality ardupilot --boot real` as a subprocess on a UDP
port (fast: a high speedup; the checks compare the vehicle clock, not wall time).
`arducopter`: the real ArduCopter SITL binary named by $ARDUCOPTER, in a temporary working
directory of its own, with ArduPilot's copter.parm and an extra parameter file, reached on
TCP SERIAL0 (5760 + 10 I) like MAVProxy reaches it; SERIAL1 (5762 + 10 I) is a second link.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

os.environ.setdefault("MAVLINK20", "1")  # pymavlink's mavutil reads this at import

from pymavlink import mavutil  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
HOME = (47.397742, 8.545594, 488.0)  # lat, lon, alt (m AMSL) of both targets' home
# SIM_FLOAT_EXCEPT 0: ArduPilot's SITL build traps floating-point exceptions and aborts where a
# flight controller carries on; a NaN in a command (SET_MESSAGE_INTERVAL param3) would kill the
# process instead of being answered. We compare with what the autopilot answers on a drone.
EXTRA_PARAMS = "ARMING_CHECK 0\nSIM_FLOAT_EXCEPT 0\n"
ARDUCOPTER_INSTANCE = int(os.environ.get("ARDUCOPTER_INSTANCE", "55"))  # -I: ports 5760 + 10 I ...


@dataclass
class Target:
    """A started autopilot: its name, clock speed and the pymavlink URLs of two links."""

    name: str
    speedup: float
    url: str  # the main link (pymavlink connection string)
    second_url_mavsdk: str  # a second link, as MAVSDK spells it
    proc: subprocess.Popen
    workdir: Path
    boot: dict = field(default_factory=dict)  # what the start-up looked like (see conftest.record_boot)
    sysid: int = 1  # the vehicle's system id (real PX4 instance i: i + 1)
    stopper: object = None  # a callable that stops it, when not `proc` alone (real PX4)

    def wall(self, sim_s: float) -> float:
        """A wall-clock bound for `sim_s` seconds of vehicle time (with slack for a loaded machine)."""
        return 3.0 + 2.5 * sim_s / self.speedup

    def stop(self) -> None:
        if callable(self.stopper):
            self.stopper()
            return
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _wait_for_line(proc: subprocess.Popen, log: Path, needle: str, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if needle in log.read_text(errors="replace"):
            return
        if proc.poll() is not None:
            raise RuntimeError(f"exited with {proc.returncode} before {needle!r}: {log.read_text(errors='replace')[-800:]}")
        time.sleep(0.05)
    raise RuntimeError(f"no {needle!r} within {timeout} s: {log.read_text(errors='replace')[-800:]}")


def start_emulator(workdir: Path, speedup: float = 20.0, personality: str = "ardupilot") -> Target:
    port = _free_udp_port()
    log = workdir / "emulator.log"
    env = {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    cmd = [sys.executable, "-m", "plmarl_sitl.cli", "autopilot", "--personality", personality, "--boot", "real",
           "--speedup", str(speedup), "--base-port", str(port), "--home", ",".join(map(str, HOME))]
    with open(log, "wb") as out:
        proc = subprocess.Popen(cmd, cwd=workdir, stdout=out, stderr=subprocess.STDOUT, env=env)
    target = Target("emulator", speedup, f"udpout:127.0.0.1:{port}", f"udpout://127.0.0.1:{port}", proc, workdir)
    try:
        _wait_for_line(proc, log, "Ctrl-C stops", 60)
    except RuntimeError:
        target.stop()
        raise
    return target


def start_arducopter(binary: str, workdir: Path, speedup: float = 10.0) -> Target:
    defaults = Path(os.environ.get("ARDUCOPTER_DEFAULTS", Path(binary).resolve().parents[3]
                                   / "Tools/autotest/default_params/copter.parm"))
    if not defaults.is_file():
        raise RuntimeError(f"no copter.parm at {defaults} (set ARDUCOPTER_DEFAULTS)")
    extra = workdir / "conformance.parm"
    extra.write_text(EXTRA_PARAMS)
    i = ARDUCOPTER_INSTANCE
    log = workdir / "arducopter.log"
    cmd = [binary, "--model", "+", "--speedup", str(speedup), "-I", str(i),
           "--home", ",".join(map(str, (*HOME, 0))), "--defaults", f"{defaults},{extra}"]
    with open(log, "wb") as out:
        proc = subprocess.Popen(cmd, cwd=workdir, stdout=out, stderr=subprocess.STDOUT)
    target = Target("arducopter", speedup, f"tcp:127.0.0.1:{5760 + 10 * i}", f"tcpout://127.0.0.1:{5762 + 10 * i}",
                    proc, workdir)
    try:
        _wait_for_line(proc, log, "Waiting for connection", 30)
    except RuntimeError:
        target.stop()
        raise
    return target


def start_real_px4(build: Path, workdir: Path) -> Target:
    """Real PX4 SITL (SIH quadrotor, at 1x in lockstep), reached on its offboard/API link as the
    agent reaches it; the GCS link (18570 + i, answers whoever sends a HEARTBEAT) is the second."""
    from conformance.px4_sitl import start_px4
    from plmarl_sitl.sitl.px4 import RUN_PARAMS

    # As a swarm's vehicles run (CA_FAILURE_MODE 1: an injected motor failure stops the motor)
    px4 = start_px4(build, workdir, home=HOME, params=dict(RUN_PARAMS))
    return Target("px4", 1.0, f"udpin:127.0.0.1:{px4.api_port}", f"udpout://127.0.0.1:{px4.gcs_port}",
                  px4.proc, workdir, sysid=px4.sysid, stopper=px4.stop)


def connect(target: Target) -> mavutil.mavfile:
    """pymavlink on the target's main link, as a ground station (sysid 255)."""
    m = mavutil.mavlink_connection(target.url, source_system=255, source_component=190, retries=10)
    m.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
    return m
