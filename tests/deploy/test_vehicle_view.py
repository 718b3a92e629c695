"""The shared MAVLink vehicle view (deploy/mavlink/vehicle_view.py) over real links: only
the autopilot component's heartbeat counts, the armed flag and mode as the emulator sets
them, home placement in the mission frame, and the optional requests: a refusal is False,
a lost link is LinkLost (not a timeout), and the error tree says which is which."""

from __future__ import annotations

import asyncio
import contextlib
import copy
import dataclasses
import gc
import logging
import math
import time
from pathlib import Path

import pytest

from plmarl_sitl.deploy.agent.config import AgentConfig
from plmarl_sitl.deploy.agent.core import Agent
from plmarl_sitl.deploy.mavlink.client import VehicleLink
from plmarl_sitl.deploy.mavlink.codec import Codec, dialect
from plmarl_sitl.deploy.mavlink.connect import connect
from plmarl_sitl.deploy.mavlink.vehicle_view import HOME_POSITION_ID, VehicleState, VehicleView, place_home
from plmarl_sitl.errors import EXIT_VEHICLE, LinkLost, VehicleLost, VehicleTimeout, VehicleUnreachable, exit_code
from plmarl_sitl.learning.nn.io import load_policy
from plmarl_sitl.mission import load_mission
from plmarl_sitl.model.geodesy import geodetic_to_ned
from plmarl_sitl.sitl.autopilot import AutopilotHost, run_realtime
from plmarl_sitl.sitl.network.broker import free_udp_ports

from .conftest import MISSION
from .scripted_autopilot import ScriptedAutopilot
from .test_agent import RecordingBus

pytestmark = pytest.mark.timeout(60)

d = dialect
ARDUPILOT_GUIDED, ARDUPILOT_LOITER, ARDUPILOT_LAND = 4, 5, 9  # ArduCopter custom_mode numbers


class TwoComponents:
    """A TCP "vehicle" (sysid 1) with its autopilot (component 1: disarmed, GUIDED) and a
    companion computer (component 191: its heartbeat claims armed and LAND). The
    companion's heartbeat is written last, so it is the link's latest HEARTBEAT."""

    def __init__(self) -> None:
        self.autopilot = Codec(1, d.MAV_COMP_ID_AUTOPILOT1)
        self.companion = Codec(1, d.MAV_COMP_ID_ONBOARD_COMPUTER)
        self.server: asyncio.Server | None = None
        self.tasks: list[asyncio.Task] = []

    def beats(self) -> bytes:
        ap = self.autopilot.mav.heartbeat_encode(d.MAV_TYPE_QUADROTOR, d.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                                 d.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, ARDUPILOT_GUIDED, d.MAV_STATE_STANDBY)
        cc = self.companion.mav.heartbeat_encode(d.MAV_TYPE_ONBOARD_CONTROLLER, d.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                                 d.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | d.MAV_MODE_FLAG_SAFETY_ARMED,
                                                 ARDUPILOT_LAND, d.MAV_STATE_ACTIVE)
        return self.autopilot.encode(ap) + self.companion.encode(cc)

    async def serve(self) -> int:
        async def client(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            self.tasks.append(asyncio.current_task())  # type: ignore[arg-type]
            with contextlib.suppress(ConnectionError):
                while not writer.is_closing():
                    writer.write(self.beats())
                    await asyncio.sleep(0.1)

        self.server = await asyncio.start_server(client, "127.0.0.1", 0)
        return self.server.sockets[0].getsockname()[1]

    def close(self) -> None:
        for t in self.tasks:
            t.cancel()
        if self.server is not None:
            self.server.close()


def test_only_the_autopilot_components_heartbeat_says_armed_and_mode() -> None:
    """A companion on the vehicle's system id claims armed and LAND; the view reads the
    autopilot's disarmed GUIDED, and a latest heartbeat from the companion says nothing."""
    async def main() -> None:
        vehicle = TwoComponents()
        port = await vehicle.serve()
        link = connect(f"tcpout://127.0.0.1:{port}")
        try:
            await link.open(timeout=5.0)
            view = VehicleView(link)
            for _ in range(5):
                state = await view.next_state(2.0)
                assert (state.armed, state.mode, state.custom_mode) == (False, "GUIDED", ARDUPILOT_GUIDED)
            companion = await link.recv("HEARTBEAT", 2.0, lambda m: m.get_srcComponent() == d.MAV_COMP_ID_ONBOARD_COMPUTER)
            assert not view.from_autopilot(companion)
            assert view.state(companion).armed  # what it would say, were it believed
            await asyncio.sleep(0.05)  # the pair is written together: the companion's is the latest
            assert link.latest["HEARTBEAT"].get_srcComponent() == d.MAV_COMP_ID_ONBOARD_COMPUTER
            assert view.latest_state() is None
        finally:
            link.close()
            vehicle.close()

    asyncio.run(main())


def test_the_armed_flag_and_mode_follow_the_emulated_autopilot() -> None:
    """ArduPilot personality of the emulator: STABILIZE disarmed, then GUIDED, then armed."""
    async def main() -> None:
        host = AutopilotHost(1, base_port=free_udp_ports(1), personality_name="ardupilot")
        await host.start()
        stop = asyncio.Event()
        clock = asyncio.create_task(run_realtime(host, 2.0, stop=stop))
        link = VehicleLink("127.0.0.1", host.ports[0])
        try:
            await link.open(timeout=5.0)
            view = VehicleView(link)
            first = await view.next_state(3.0)
            assert not first.armed and first.mode != "GUIDED"
            await link.set_mode("GUIDED")
            await link.arm()
            for _ in range(20):  # the next heartbeat may have left before the command
                state = await view.next_state(3.0)
                if state.armed:
                    break
            assert (state.armed, state.mode) == (True, "GUIDED")
            assert view.latest_state() == state  # the emulator is the only component
        finally:
            link.close()
            stop.set()
            await clock
            host.close()

    asyncio.run(main())


def test_home_placement_in_the_mission_frame() -> None:
    """The local frame's origin = the home's NED offset from the mission origin minus the
    home's local x, y, z (ArduPilot's EKF origin need not be the home); NaN local: home."""
    o = (47.3977, 8.5456, 488.0)
    home_ll = (47.3986, 8.5470, 490.5)
    h = geodetic_to_ned(*o, *home_ll)
    mav = Codec(1, 1).mav

    def home(x: float, y: float, z: float):  # noqa: ANN202 - a pymavlink message
        return mav.home_position_encode(int(home_ll[0] * 1e7), int(home_ll[1] * 1e7), int(home_ll[2] * 1000), x, y, z,
                                        [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, 0)

    placed = place_home(*o, home(3.0, -4.0, -0.5))
    assert (placed.lat_deg, placed.lon_deg, placed.alt_m) == pytest.approx(home_ll, abs=1e-7)
    assert placed.local == (3.0, -4.0, -0.5)
    assert placed.origin == pytest.approx((h[0] - 3.0, h[1] + 4.0, h[2] + 0.5))
    assert h[0] == pytest.approx(100.0, abs=1.0) and h[2] == pytest.approx(-2.5, abs=0.01)  # 0.0009 deg north, 2.5 m up
    nan = place_home(*o, home(math.nan, math.nan, math.nan))
    assert nan.local == (0.0, 0.0, 0.0) and nan.origin == pytest.approx(h)


def test_requests_refused_are_false_and_a_lost_link_is_link_lost() -> None:
    """An autopilot that DENIES the optional requests: False, and the home it streams
    anyway still comes; the autopilot hangs up: LinkLost at once, not a 3 x 1 s retry."""
    async def main() -> None:
        ap = ScriptedAutopilot(result=d.MAV_RESULT_DENIED, home=(47.3986, 8.5470, 490.5))
        port = await ap.serve_tcp()
        link = connect(f"tcpout://127.0.0.1:{port}")
        try:
            await link.open(timeout=5.0)
            view = VehicleView(link)
            with link.subscribe("HOME_POSITION") as homes:
                assert await view.request(HOME_POSITION_ID) is False
                assert (await homes.next(2.0)).latitude == int(47.3986e7)
            assert await view.stream("LOCAL_POSITION_NED", 10.0) is False
            ap.hang_up()
            t0 = time.monotonic()
            with pytest.raises(LinkLost):
                await view.request(HOME_POSITION_ID)
            with pytest.raises(LinkLost):
                await view.stream("LOCAL_POSITION_NED", 10.0)
            with pytest.raises(LinkLost):
                await view.next_state(3.0)
            assert time.monotonic() - t0 < 1.0
        finally:
            link.close()
            ap.close()

    asyncio.run(main())


def test_link_lost_and_vehicle_timeout_are_siblings() -> None:
    """A handler of a timeout (retry, advice) does not catch a lost link; both are a
    VehicleUnreachable, a flight ends with VehicleLost on either, exit code 3 for both."""
    lost, silent = LinkLost(3, "tcp 127.0.0.1:5760: the autopilot closed the connection"), VehicleTimeout(3, "HEARTBEAT", 2.0)
    assert not isinstance(lost, VehicleTimeout) and not isinstance(silent, LinkLost)
    assert isinstance(lost, VehicleUnreachable) and isinstance(silent, VehicleUnreachable)
    assert str(lost) == "vehicle 3: link lost (tcp 127.0.0.1:5760: the autopilot closed the connection)"
    assert lost.sysid == silent.sysid == 3 and lost.reason.startswith("tcp")
    assert str(VehicleLost(lost)) == f"vehicle lost: {lost}" and str(VehicleLost(silent)) == "vehicle lost: vehicle 3: no HEARTBEAT within 2 s"
    assert exit_code(lost) == exit_code(silent) == EXIT_VEHICLE
    with pytest.raises(LinkLost):  # what the agent's start-up waits rely on
        try:
            raise lost
        except VehicleTimeout:
            pytest.fail("a timeout handler caught a lost link")


@contextlib.asynccontextmanager
async def _flying_session(policy_dir: Path, personality: str, rate: float):
    """A one-vehicle emulator run in real time at `rate`, an open link to it, its view, and an
    agent's session that believes itself flying (as after its take-off); all closed after."""
    mission = dataclasses.replace(load_mission(MISSION), n_uavs=1)
    host = AutopilotHost(1, base_port=free_udp_ports(1), personality_name=personality)
    await host.start()
    stop = asyncio.Event()
    clock = asyncio.create_task(run_realtime(host, rate, stop=stop))
    link = VehicleLink("127.0.0.1", host.ports[0])
    session = None
    try:
        await link.open(timeout=5.0)
        cfg = AgentConfig(uav_id=0, connect_url=f"udpout://127.0.0.1:{host.ports[0]}", mission=mission)
        session = Agent(cfg, load_policy(policy_dir, mission), RecordingBus(), link).session
        session.personality, session.flying = link.personality, True
        yield link, VehicleView(link), session
    finally:
        if session is not None:
            session.close()  # a re-engage may still be waiting for its acknowledgement
        link.close()
        await asyncio.sleep(0.3)  # past a command's resend: a task left alive would send now
        stop.set()
        await clock
        host.close()


def test_the_agent_reengages_after_a_failsafe_and_stops_by_the_views_heartbeat(
        policy_dir: Path, caplog: pytest.LogCaptureFixture) -> None:
    """The agent's session reads the autopilot's state through the view: armed in the
    personality's hold mode (ArduPilot LOITER, a setpoint-loss failsafe) it asks for GUIDED
    back; stopping, it commands BRAKE to an armed vehicle and leaves a disarmed one alone."""
    caplog.set_level(logging.INFO, logger="plmarl.agent")

    async def main() -> None:
        async with _flying_session(policy_dir, "ardupilot", 2.0) as (link, view, session):
            await link.set_mode("LOITER")
            await link.arm()
            while not (await view.next_state(3.0)).armed:
                pass
            assert view.latest_state() == VehicleState(True, "LOITER", ARDUPILOT_LOITER)
            session._check_mode()
            assert session.reengaged == 1
            for _ in range(20):
                if (await view.next_state(3.0)).mode == "GUIDED":
                    break
            assert view.latest_state().mode == "GUIDED"
            await session.hold()
            assert (await view.next_state(3.0)).mode == "BRAKE"
            await link.disarm(force=True)
            while (await view.next_state(3.0)).armed:
                pass
            await session.hold()

    asyncio.run(main())
    said = [r.getMessage() for r in caplog.records if r.name == "plmarl.agent"]
    assert "vehicle fell back to LOITER (setpoint-loss failsafe); re-engaging GUIDED" in said
    assert "stopped: vehicle in BRAKE" in said
    assert "stopped: vehicle left to its autopilot (BRAKE, disarmed)" in said


def test_a_heartbeat_from_before_our_own_offboard_switch_is_no_failsafe(
        policy_dir: Path, caplog: pytest.LogCaptureFixture) -> None:
    """Issue 28: PX4 acknowledges OFFBOARD and shows it only in its next 1 Hz heartbeat, so the
    heartbeat in hand right after the switch still says AUTO.LOITER. That is not a
    setpoint-loss failsafe (the agent used to warn "fell back" 0.1 s after every switch on a
    real PX4); a hold-mode heartbeat that comes later still is."""
    caplog.set_level(logging.INFO, logger="plmarl.agent")

    async def main() -> None:
        async with _flying_session(policy_dir, "px4", 4.0) as (link, view, session):
            await link.arm()
            while not (await view.next_state(3.0)).armed:
                pass
            stale = link.latest["HEARTBEAT"]  # armed, AUTO.LOITER: what PX4 sent before the switch
            assert view.state(stale).mode == "AUTO.LOITER"
            for _ in range(5):
                link.send_accel_ned(0.0, 0.0, 0.0)
                await asyncio.sleep(0.02)
            await session._set_mode("OFFBOARD")
            link.latest["HEARTBEAT"] = stale  # as on PX4: no new heartbeat yet
            for _ in range(3):
                session._check_mode()
                await asyncio.sleep(0.15)
            assert session.reengaged == 0
            await asyncio.sleep(0.4)  # later, a (new) hold-mode heartbeat is a failsafe again
            link.latest["HEARTBEAT"] = copy.copy(stale)
            session._check_mode()  # first seen now: after MODE_ECHO_S
            assert session.reengaged == 1  # and its re-engage is still in flight at the close

    caplog.set_level(logging.INFO, logger="asyncio")
    asyncio.run(main())
    gc.collect()  # a task that died with nobody awaiting it says so when it is collected
    said = [r.getMessage() for r in caplog.records if r.name == "plmarl.agent"]
    assert said.count("vehicle fell back to AUTO.LOITER (setpoint-loss failsafe); re-engaging OFFBOARD") == 1
    assert not [r.getMessage() for r in caplog.records if r.name == "asyncio"], "a task outlived the closed session"
