"""The shipped agent against a REAL ArduCopter SITL (issue 13): set ARDUCOPTER to the
`arducopter` binary built from ArduPilot's source; without it these tests skip.

Each test starts its own ArduCopter (its own temporary working directory, instance -I in
40..49 so its ports do not collide, `--speedup 5`, the frame `+`, ArduPilot's copter.parm
plus ARMING_CHECK 0) and runs `plmarl agent` from another directory with the project's
default mission and policy, `--bus direct`, on a mosquitto broker. A pymavlink client on
SERIAL1 watches what the vehicle does. Timings are printed (run with -s to see them)."""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import os
import shutil
import socket
import subprocess
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from plmarl_sitl.errors import EXIT_USER
from plmarl_sitl.mission import load_mission
from plmarl_sitl.model.geodesy import ned_to_geodetic
from plmarl_sitl.sitl.network.broker import MosquittoBroker
from plmarl_sitl.twin.env import launch_positions

from .agent_process import run_agent
from .conftest import MISSION

os.environ.setdefault("MAVLINK20", "1")  # before pymavlink's mavutil is imported

BINARY = os.environ.get("ARDUCOPTER", "")
pytestmark = [
    pytest.mark.integration,
    pytest.mark.slow,
    pytest.mark.timeout(300),
    pytest.mark.skipif(not BINARY, reason="set ARDUCOPTER=/path/to/arducopter (a real ArduCopter SITL binary) to run"),
    pytest.mark.skipif(not shutil.which("mosquitto") and not os.path.exists("/usr/sbin/mosquitto"), reason="mosquitto not installed"),
]

SPEEDUP = 5
INSTANCES = range(40, 50)  # -I: ports 5760 + 10 I (SERIAL0), 5762 + 10 I (SERIAL1), 5763 + 10 I
ACCEL_ONLY = 0x0C3F  # the agent's SET_POSITION_TARGET_LOCAL_NED type mask
GUIDED = 4


def copter_defaults() -> Path:
    """ArduPilot's copter.parm: ARDUCOPTER_DEFAULTS, else found from the binary's build tree."""
    given = os.environ.get("ARDUCOPTER_DEFAULTS")
    if given:
        return Path(given)
    for parent in Path(BINARY).resolve().parents:
        p = parent / "Tools" / "autotest" / "default_params" / "copter.parm"
        if p.exists():
            return p
    pytest.skip(f"no Tools/autotest/default_params/copter.parm above {BINARY}; set ARDUCOPTER_DEFAULTS")


def _tcp_free(port: int) -> bool:
    with socket.socket() as s:
        try:
            s.bind(("0.0.0.0", port))
        except OSError:
            return False
    return True


def free_instance() -> int:
    for i in INSTANCES:
        if all(_tcp_free(5760 + 10 * i + k) for k in (0, 2, 3)):
            return i
    pytest.skip(f"no free ArduPilot SITL instance in -I {INSTANCES.start}..{INSTANCES.stop - 1}")


@dataclass
class ArduCopter:
    instance: int
    workdir: Path
    proc: subprocess.Popen

    @property
    def serial0(self) -> int:
        return 5760 + 10 * self.instance

    @property
    def serial1(self) -> int:
        return 5762 + 10 * self.instance

    def log(self) -> str:
        return (self.workdir / "arducopter.log").read_text(errors="replace")


@contextlib.contextmanager
def arducopter(tmp: Path, home: tuple[float, float, float, float] | None) -> Iterator[ArduCopter]:
    """A real ArduCopter in `tmp` (eeprom.bin, logs/ go there), stopped on exit. It waits for
    a client on SERIAL0 before its clock starts."""
    tmp.mkdir(parents=True, exist_ok=True)
    extra = tmp / "test.parm"
    extra.write_text("ARMING_CHECK 0\n")
    i = free_instance()
    cmd = [BINARY, "--model", "+", "--speedup", str(SPEEDUP), "-I", str(i), "--defaults", f"{copter_defaults()},{extra}"]
    if home is not None:
        cmd += ["--home", ",".join(f"{x:.7f}" for x in home)]
    with open(tmp / "arducopter.log", "wb") as out:
        proc = subprocess.Popen(cmd, cwd=tmp, stdout=out, stderr=subprocess.STDOUT, start_new_session=True)
    ac = ArduCopter(i, tmp, proc)
    try:
        deadline = time.monotonic() + 20
        while _tcp_free(ac.serial0):  # listening?
            assert proc.poll() is None, f"arducopter exited {proc.returncode}:\n{ac.log()}"
            assert time.monotonic() < deadline, f"arducopter did not open SERIAL0 in 20 s:\n{ac.log()}"
            time.sleep(0.1)
        yield ac
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@dataclass
class Watch:
    """What a pymavlink client on SERIAL1 saw (wall time since the agent started)."""

    armed_guided_at: float | None = None
    max_rel_alt_m: float = 0.0
    accel_echoes: list[tuple[float, int, float, float, float]] = field(default_factory=list)
    error: str | None = None


def watch_serial1(port: int, t0: float, stop: threading.Event, seen: Watch) -> None:
    """A second GCS on SERIAL1 (opens once SERIAL0 has a client): heartbeat, relative
    altitude, and the position target ArduCopter echoes."""
    from pymavlink import mavutil

    try:
        deadline = time.monotonic() + 30
        while True:
            try:
                m = mavutil.mavlink_connection(f"tcp:127.0.0.1:{port}", source_system=250, source_component=190,
                                               autoreconnect=False)
                break
            except OSError:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.5)
        m.wait_heartbeat(timeout=30)
        mav = m.mav
        for msgid, hz in ((85, 10.0), (33, 5.0)):  # POSITION_TARGET_LOCAL_NED, GLOBAL_POSITION_INT
            # Params as the spec says: 3-6 reserved (0), 7 response target (0: default).
            mav.command_long_send(m.target_system, m.target_component, mavutil.mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                  msgid, 1e6 / hz, 0, 0, 0, 0, 0)
        last_hb = 0.0
        while not stop.is_set():
            now = time.monotonic()
            if now - last_hb > 1.0:
                mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
                last_hb = now
            msg = m.recv_match(type=["HEARTBEAT", "GLOBAL_POSITION_INT", "POSITION_TARGET_LOCAL_NED"], blocking=True, timeout=0.5)
            if msg is None:
                continue
            t = time.monotonic() - t0
            kind = msg.get_type()
            if kind == "HEARTBEAT" and msg.get_srcComponent() == 1:
                if msg.base_mode & 128 and msg.custom_mode == GUIDED and seen.armed_guided_at is None:
                    seen.armed_guided_at = t
            elif kind == "GLOBAL_POSITION_INT":
                seen.max_rel_alt_m = max(seen.max_rel_alt_m, msg.relative_alt / 1000.0)
            elif kind == "POSITION_TARGET_LOCAL_NED" and msg.type_mask == ACCEL_ONLY:
                seen.accel_echoes.append((t, msg.type_mask, msg.afx, msg.afy, msg.afz))
        m.close()
    except Exception as exc:  # noqa: BLE001 - reported by the test
        seen.error = f"{type(exc).__name__}: {exc}"


def launch_slot_home() -> tuple[float, float, float, float]:
    """lat, lon, alt, heading of the mission's launch slot 0 for a one-UAV swarm."""
    m = dataclasses.replace(load_mission(MISSION), n_uavs=1)
    north, east, _ = launch_positions(m, 0.0)[0].tolist()
    lat, lon, alt = ned_to_geodetic(m.origin.lat_deg, m.origin.lon_deg, m.origin.alt_m, north, east, 0.0)
    return lat, lon, alt, 0.0


def _timeline(lines: list[tuple[float, str]], keys: list[str]) -> dict[str, float]:
    out = {}
    for key in keys:
        hit = next((t for t, line in lines if key in line), None)
        if hit is not None:
            out[key] = round(hit, 2)
    return out


AGENT_STEPS = ["policy loaded", "personality", "waiting up to 120 s for the autopilot's local position", "ready after",
               "taking off", "in GUIDED", "mission clock"]


def test_the_shipped_agent_flies_a_real_arducopter_in_guided(tmp_path: Path) -> None:
    """From another directory, defaults only: GUIDED, armed, climbs to the mission's 60 m,
    and ArduCopter echoes the agent's acceleration setpoints."""
    seen = Watch()
    stop = threading.Event()
    lines: list[tuple[float, str]] = []

    with arducopter(tmp_path / "ac", launch_slot_home()) as ac, MosquittoBroker() as broker:
        t0 = time.monotonic()
        watcher = threading.Thread(target=watch_serial1, args=(ac.serial1, t0, stop, seen), daemon=True)
        guided: list[float] = []

        def on_line(line: str) -> None:
            lines.append((time.monotonic() - t0, line.rstrip()))
            if "personality" in line:
                watcher.start()  # SERIAL1 opens once SERIAL0 has its client
            if "in GUIDED" in line:
                guided.append(time.monotonic() - t0)

        def flown_enough() -> bool:  # ArduCopter echoed the agent's setpoints for 5 s after GUIDED
            echoed = [t for t, *_ in seen.accel_echoes if guided and t >= guided[0]]
            return len(echoed) >= 2 and echoed[-1] - echoed[0] >= 5.0

        run = asyncio.run(run_agent(
            ["--id", "0", "--n-uavs", "1", "--connect", f"tcpout://127.0.0.1:{ac.serial0}", "--broker", broker.url,
             "--bus", "direct", "--no-auth"], cwd=tmp_path, timeout_s=240, on_line=on_line, interrupt_when=flown_enough))
        stop.set()
        if watcher.is_alive():
            watcher.join(5)

    timeline = _timeline(lines, AGENT_STEPS)
    print(f"\nreal ArduCopter x{SPEEDUP}, -I {ac.instance}: agent timeline (wall s from agent start): {timeline}")
    print(f"watcher: armed+GUIDED at {seen.armed_guided_at}, max relative alt {seen.max_rel_alt_m:.1f} m, "
          f"{len(seen.accel_echoes)} accel echoes, first {seen.accel_echoes[:1]}")
    assert seen.error is None, seen.error
    assert run.code == 0, run.err + "\n" + ac.log()[-2000:]
    assert "taking off to 60 m above home" in run.err and "in GUIDED at" in run.err, run.err
    assert seen.armed_guided_at is not None, run.err
    assert seen.max_rel_alt_m >= 55.0, (seen.max_rel_alt_m, run.err)
    assert len(seen.accel_echoes) >= 10, run.err
    assert all(abs(a) <= 20 and abs(b) <= 20 and abs(c) <= 20 for _, _, a, b, c in seen.accel_echoes)
    assert "stopped: vehicle in BRAKE" in run.err, run.err


def test_with_arducopters_default_home_the_agent_exits_with_the_far_home_error(tmp_path: Path) -> None:
    """No --home: ArduCopter starts in Canberra, the mission is in Zurich."""
    lines: list[tuple[float, str]] = []
    with arducopter(tmp_path / "ac", None) as ac, MosquittoBroker() as broker:
        t0 = time.monotonic()

        def on_line(line: str) -> None:
            lines.append((time.monotonic() - t0, line.rstrip()))

        run = asyncio.run(run_agent(["--id", "0", "--n-uavs", "1", "--connect", f"tcpout://127.0.0.1:{ac.serial0}",
                                     "--broker", broker.url, "--bus", "direct", "--no-auth"], cwd=tmp_path, timeout_s=120, on_line=on_line))
    print(f"\nreal ArduCopter x{SPEEDUP}, default home: far-home error at {lines[-1][0]:.2f} s: {lines[-1][1]}")
    assert "Traceback" not in run.err, run.err
    assert run.code == EXIT_USER, run.err
    [line] = run.errors()
    assert "-35.36326" in line and "149.16523" in line and "47.397742, 8.545594" in line, line
