"""The pieces of missions on real autopilots, each on its own (no processes, no sockets
except where a bound port is the point): the world's view of external vehicles and their
clocks, the agent's per-vehicle t0, the ArduCopter command lines and the CLI's errors."""

from __future__ import annotations

import asyncio
import dataclasses
import logging
import math
import subprocess
import sys
import time
from collections import deque
from pathlib import Path
from types import SimpleNamespace

import pytest

from plmarl_sitl.deploy.agent.clock import MissionClock
from plmarl_sitl.deploy.agent.demand import DemandMaps
from plmarl_sitl.deploy.agent.inbox import Inbox
from plmarl_sitl.deploy.agent.neighbours import NeighbourTable
from plmarl_sitl.deploy.mqtt.schema import Topics, encode_json
from plmarl_sitl.deploy.mqtt.transport import MqttBus
from plmarl_sitl.errors import UserError
from plmarl_sitl.mission import load_mission
from plmarl_sitl.model.geodesy import geodetic_to_ned
from plmarl_sitl.sitl.arducopter import ArduCopterFleet, find_copter_parm, free_instance_base, launch_homes
from plmarl_sitl.sitl.external import ExternalVehicles
from plmarl_sitl.sitl.network.broker import free_port
from plmarl_sitl.twin.env import launch_positions

ROOT = Path(__file__).resolve().parents[2]
MISSION = ROOT / "missions" / "paper_urban.yaml"


def two_uavs():
    return dataclasses.replace(load_mission(MISSION), n_uavs=2)


# ---------------------------------------------------------------------------- external vehicles
def test_external_vehicles_follow_the_slowest_clock_and_give_t0_on_each_vehicles_own_clock() -> None:
    ext = ExternalVehicles(two_uavs(), ["tcpout://127.0.0.1:5762", "udpin://0.0.0.0:14550"], speedup=5.0)
    a, b = ext.vehicles
    home = SimpleNamespace(latitude=int(47.4022335e7), longitude=int(8.5515659e7), altitude=488_000, x=1.0, y=2.0, z=0.0)
    for v in (a, b):
        v.origin = (0.0, 0.0, 0.0)
        v.local = (0.0, 0.0, -60.0, 0.0, 0.0, 0.0)
    long_ago = time.perf_counter() - 100.0
    a.observe(100.0, long_ago)  # vehicle 1 booted 62.5 vehicle seconds later than vehicle 0
    b.observe(37.5, long_ago)
    assert ext.now == -math.inf  # not heard lately: their clocks hold nothing
    t0s = ext.start_times(110.0)
    assert t0s == pytest.approx([110.0, 47.5], abs=1e-3)
    assert ext.frozen
    # The vehicles report at the same wall instant; the slower clock decides what `now` is.
    w = time.perf_counter()
    a.observe(120.0, w)
    b.observe(57.0, w)  # 0.5 s behind vehicle 0 on the common reference
    assert ext.now == pytest.approx(57.0 - (47.5 - 110.0))
    ext.kill(1)  # a failed vehicle no longer holds the clock back
    assert ext.now == pytest.approx(120.0)
    # Placement as the agent's: home known in both frames.
    ext_place = ExternalVehicles(two_uavs(), ["udpout://127.0.0.1:1", "udpout://127.0.0.1:2"])
    v = ext_place.vehicles[0]
    ext_place.place(v, home)
    o = two_uavs().origin
    h = geodetic_to_ned(o.lat_deg, o.lon_deg, o.alt_m, 47.4022335, 8.5515659, 488.0)
    assert v.origin == pytest.approx((h[0] - 1.0, h[1] - 2.0, h[2]))


def test_external_vehicles_say_what_each_one_waits_for() -> None:
    ext = ExternalVehicles(two_uavs(), ["udpout://127.0.0.1:1", "udpout://127.0.0.1:2"])
    a, b = ext.vehicles
    assert ext.not_ready(60.0) == ["0 (not connected yet)", "1 (not connected yet)"]
    assert not bool(ext.alive().any())
    for v in (a, b):
        v.offboard_mode, v.mode, v.armed = "GUIDED", "GUIDED", True
        v.origin = (500.0, 450.0, 0.0)
    a.local = (0.0, 0.0, -60.0, 0.0, 0.0, 0.1)
    b.local = (0.0, 0.0, -40.0, 0.0, 0.0, -2.0)
    assert ext.not_ready(60.0) == ["1 (GUIDED, armed, 40.0 m, climbing)"]
    assert ext.positions()[0].tolist() == [500.0, 450.0, -60.0]


def test_external_vehicles_want_one_good_url_per_uav() -> None:
    with pytest.raises(UserError, match="1 vehicle URL"):
        ExternalVehicles(two_uavs(), ["udpout://127.0.0.1:1"])
    with pytest.raises(UserError, match="scheme"):
        ExternalVehicles(two_uavs(), ["udpout://127.0.0.1:1", "http://x:2"])


# ---------------------------------------------------------------------------- the agent's t0
def test_the_agent_takes_t0_on_its_own_vehicles_clock_from_the_start_message() -> None:
    topics = Topics("sitl")
    for me, want in ((0, 81.0), (1, 80.809)):
        clock = MissionClock(15, 3, 0.1, 0.15)
        inbox = Inbox(topics, me, 2, NeighbourTable(2, me, 2), clock, deque(), DemandMaps(two_uavs(), topics.demand),
                      wait_start=True)
        inbox.on_message(topics.start, encode_json({"t0_boot_s": 81.0, "tup_s": 15, "n_uavs": 2,
                                                    "t0_boot_s_by_uav": [81.0, 80.809]}))
        assert clock.t0 == want
    clock = MissionClock(15, 3, 0.1, 0.15)  # a shared clock: one t0 for all
    Inbox(topics, 1, 2, NeighbourTable(2, 1, 2), clock, deque(), DemandMaps(two_uavs(), topics.demand), wait_start=True).on_message(
        topics.start, encode_json({"t0_boot_s": 81.0, "tup_s": 15, "n_uavs": 2}))
    assert clock.t0 == 81.0
    inbox = Inbox(topics, 3, 4, NeighbourTable(4, 3, 2), MissionClock(15, 3, 0.1, 0.15), deque(),
                  DemandMaps(two_uavs(), topics.demand), wait_start=True)
    inbox.on_message(topics.start, encode_json({"t0_boot_s": 81.0, "t0_boot_s_by_uav": [81.0]}))  # too short
    assert inbox.rx.as_dict().get("malformed_start") == 1


# ---------------------------------------------------------------------------- ArduCopter processes
def test_arducopter_command_line_puts_each_vehicle_at_its_launch_slot(tmp_path: Path) -> None:
    m = two_uavs()
    fleet = ArduCopterFleet(Path("/opt/arducopter"), Path("/opt/copter.parm"), m, 5.0, tmp_path, instance_base=60)
    cmd = fleet.command(1, tmp_path / "v1")
    assert cmd[:5] == ["/opt/arducopter", "--model", "+", "--speedup", "5"]
    assert cmd[cmd.index("-I") + 1] == "61" and cmd[cmd.index("--sysid") + 1] == "2"
    assert cmd[cmd.index("--defaults") + 1] == f"/opt/copter.parm,{tmp_path / 'v1' / 'plmarl.parm'}"
    lat, lon, alt, heading = (float(x) for x in cmd[cmd.index("--home") + 1].split(","))
    o = m.origin
    north, east, down = geodetic_to_ned(o.lat_deg, o.lon_deg, o.alt_m, lat, lon, alt)
    slot = launch_positions(m, 0.0)[1]
    assert (north, east) == pytest.approx((float(slot[0]), float(slot[1])), abs=0.02)
    assert down == pytest.approx(0.0, abs=0.01) and heading == 0.0
    assert len(launch_homes(m)) == 2


def test_arducopter_defaults_are_absolute_paths_with_a_relative_run_directory(tmp_path: Path, monkeypatch) -> None:  # noqa: ANN001
    """arducopter runs in its vehicle directory; `swarm up`'s run directory is relative
    (runs/...). A relative --defaults made every ArduCopter PANIC on its first connection."""
    monkeypatch.chdir(tmp_path)
    fleet = ArduCopterFleet(Path("/opt/arducopter"), Path("ardupilot/copter.parm"), two_uavs(), 5.0, Path("runs/x"), instance_base=60)
    workdir = Path("runs/x/arducopter/vehicle0")
    parms = fleet.command(0, workdir)[-1].split(",")
    assert parms == [str(tmp_path / "ardupilot" / "copter.parm"), str(tmp_path / workdir / "plmarl.parm")]
    assert all(Path(x).is_absolute() for x in parms)


def test_copter_parm_is_found_in_the_ardupilot_tree_or_named_in_one_line(tmp_path: Path) -> None:
    tree = tmp_path / "ardupilot"
    binary = tree / "build" / "sitl" / "bin" / "arducopter"
    binary.parent.mkdir(parents=True)
    binary.write_text("")
    with pytest.raises(UserError, match="copter.parm") as exc:
        find_copter_parm(binary)
    assert "\n" not in str(exc.value)
    parm = tree / "Tools" / "autotest" / "default_params" / "copter.parm"
    parm.parent.mkdir(parents=True)
    parm.write_text("FRAME_CLASS 1\n")
    assert find_copter_parm(binary) == parm
    with pytest.raises(UserError, match="no such file"):
        find_copter_parm(binary, tmp_path / "missing.parm")


@pytest.mark.parametrize("argv, needle", [
    (["--autopilot", "arducopter=/nonexistent/arducopter"], "no such file"),
    (["--autopilot", "arducopter"], "expected emulator, arducopter=PATH"),
    (["--autopilot", "px4"], "or px4=PATH"),
    (["--instance", "60"], "are for --autopilot arducopter=PATH"),
])
def test_swarm_up_autopilot_errors_are_one_line(argv: list[str], needle: str, tmp_path: Path) -> None:
    r = subprocess.run([sys.executable, "-m", "plmarl_sitl.cli", "swarm", "up", str(MISSION), "--out", str(tmp_path / "run"), *argv],
                       capture_output=True, text=True, timeout=60, cwd=ROOT)
    assert r.returncode == 2, r.stderr
    lines = [x for x in r.stderr.splitlines() if x.strip()]
    assert needle in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert len([x for x in lines if "error" in x]) == 1, r.stderr


# ---------------------------------------------------------------------------- the bus
def test_an_unreachable_broker_is_a_warning_naming_it(caplog: pytest.LogCaptureFixture) -> None:
    url = f"mqtt://127.0.0.1:{free_port()}"  # nobody listens

    async def main() -> None:
        bus = MqttBus(url, "t", [], lambda t, p: None, name="test-bus")
        task = asyncio.create_task(bus.run())
        await asyncio.sleep(1.0)
        task.cancel()
        with pytest.raises(asyncio.CancelledError):
            await task

    with caplog.at_level(logging.INFO, logger="plmarl.bus"):
        asyncio.run(main())
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert len(warnings) == 1, warnings  # once, not at every retry
    assert url in warnings[0] and "retrying" in warnings[0]


# A stand-in for a real arducopter that fails the way one with a bad --defaults does: it
# listens on SERIAL0, and on the first connection prints PANIC and exits (the real binary
# is exercised in test_real_arducopter*.py, which need ARDUCOPTER).
_PANICS_ON_CONNECT = """
import socket, sys
base = 5760 + 10 * int(sys.argv[sys.argv.index("-I") + 1])
srv = socket.socket(); srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
srv.bind(("127.0.0.1", base)); srv.listen(1)
print("Waiting for connection ....", flush=True)
srv.accept()
print("PANIC: Failed to load defaults from " + sys.argv[sys.argv.index("--defaults") + 1], flush=True)
sys.exit(1)
"""


def test_an_arducopter_that_exits_while_its_key_is_provisioned_is_named_with_its_log(tmp_path: Path) -> None:
    binary = tmp_path / "arducopter"
    binary.write_text(f"#!{sys.executable}\n{_PANICS_ON_CONNECT}")
    binary.chmod(0o755)
    fleet = ArduCopterFleet(binary, tmp_path / "copter.parm", two_uavs(), 5.0, tmp_path / "run", free_instance_base(2, 70))

    async def main() -> str:
        fleet.start()
        try:
            await fleet.wait_listening(10.0)
            with pytest.raises(RuntimeError) as err:
                await fleet.provision_signing([bytes(32), bytes(32)], timeout_s=5.0)
            return str(err.value)
        finally:
            await fleet.stop()

    msg = asyncio.run(main())
    assert msg.startswith("arducopter ") and "exited with code 1" in msg and "PANIC: Failed to load defaults" in msg, msg
    assert "arducopter.log" in msg and "\n" not in msg


def test_external_vehicles_follow_an_emulated_autopilot_through_the_vehicle_view() -> None:
    """The world's own link to an autopilot elsewhere (here the emulator's UDP port): the
    stream and home are asked for, the home placed as the agent places it, and the armed
    flag and mode read from the autopilot's heartbeat as the agent reads them."""
    from plmarl_sitl.deploy.mavlink.client import VehicleLink
    from plmarl_sitl.sitl.autopilot import AutopilotHost, run_realtime
    from plmarl_sitl.sitl.network.broker import free_udp_ports

    mission = dataclasses.replace(load_mission(MISSION), n_uavs=1)
    home_ned = (420.0, -135.0, 0.0)  # where the emulator puts the vehicle's home, in the mission frame

    async def main() -> tuple:
        host = AutopilotHost(1, base_port=free_udp_ports(1), personality_name="ardupilot", origin=mission.origin,
                             home_offsets_ned=[home_ned])
        await host.start()
        stop = asyncio.Event()
        clock = asyncio.create_task(run_realtime(host, 2.0, stop=stop))
        ext = ExternalVehicles(mission, [f"udpout://127.0.0.1:{host.ports[0]}"])
        pilot = VehicleLink("127.0.0.1", host.ports[0])
        try:
            await ext.start()
            v = ext.vehicles[0]
            t_end = time.monotonic() + 20.0
            while not v.flying_data() and time.monotonic() < t_end:
                await asyncio.sleep(0.1)
            seen = (v.state, v.mode, v.armed, v.origin, v.offboard_mode)
            await pilot.open(timeout=5.0)
            await pilot.set_mode("GUIDED")
            await pilot.arm()
            while not (v.armed and v.mode == "GUIDED") and time.monotonic() < t_end:
                await asyncio.sleep(0.1)
            return seen, (v.mode, v.armed), v.position()
        finally:
            pilot.close()
            ext.close()
            stop.set()
            await clock
            host.close()

    (state, mode, armed, origin, offboard), after, pos = asyncio.run(main())
    assert origin is not None, state
    assert offboard == "GUIDED" and not armed and mode != "GUIDED"
    assert after == ("GUIDED", True)
    assert pos == pytest.approx(home_ned, abs=0.5)  # on the ground at its home, in the mission frame
