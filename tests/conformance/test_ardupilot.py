"""Differential conformance: the same pymavlink (and MAVSDK) checks against the emulator's
ArduPilot personality and, with ARDUCOPTER=/path/to/arducopter, a real ArduCopter SITL.

The expected values are what the real ArduCopter 4.7 answers (measured; docs/CONFORMANCE.md),
so a test passing on both targets means they agree. The tests of this module run in file
order on one started vehicle per target: start-up, commands on the ground, a flight, a landing.
Times are vehicle seconds (time_boot_ms), the same at any speedup.
"""

from __future__ import annotations

import asyncio
import math

import pytest
from pymavlink import mavutil

from conformance.link import Link
from conformance.targets import Target

pytestmark = [pytest.mark.integration, pytest.mark.conformance, pytest.mark.timeout(180)]

mav = mavutil.mavlink
NAN = math.nan
GUIDED, LOITER, LAND, STABILIZE = 4, 5, 9, 0
ACCEL_ONLY = 0x0C3F
TAKEOFF_ALT_M = 10.0
# Start-up instants of the real one (vehicle seconds after its link came up), and how far
# either target may be from them: the real EKF's timing varies a little from run to run.
HOME_AT_S, POSITION_AT_S, BOOT_TOLERANCE_S = 19.0, 40.0, 4.0


def _set_mode(link: Link, custom_mode: int) -> int | None:
    return link.command(mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, custom_mode, 0, 0, 0, 0, 0)


def _wait_mode(link: Link, custom_mode: int) -> None:
    assert link.wait("HEARTBEAT", lambda h: h.custom_mode == custom_mode, sim_s=3.0) is not None, f"mode {custom_mode}"


# ---------------------------------------------------------------------------- start-up


def test_heartbeat_fields(target: Target) -> None:
    hb = target.boot["heartbeat"]
    assert hb is not None, "no HEARTBEAT"
    assert (hb.get_srcSystem(), hb.get_srcComponent()) == (1, mav.MAV_COMP_ID_AUTOPILOT1)
    assert (hb.autopilot, hb.type, hb.mavlink_version) == (mav.MAV_AUTOPILOT_ARDUPILOTMEGA, mav.MAV_TYPE_QUADROTOR, 3)
    # ArduCopter's base_mode(): CUSTOM_MODE | STABILIZE | MANUAL_INPUT, not armed, and GUIDED_ENABLED
    # while its position controller runs (not at the first heartbeat; a known difference). Boots in STABILIZE.
    assert hb.base_mode & ~mav.MAV_MODE_FLAG_GUIDED_ENABLED == 81 and hb.custom_mode == STABILIZE


def test_boot_statustexts_in_order(target: Target) -> None:
    texts = [t for _, t in target.boot["texts"]]
    wanted = ["ArduPilot Ready", "EKF3 IMU0 initialised", "EKF3 IMU0 origin set", "EKF3 IMU0 is using GPS"]
    found = [t for t in texts if t in wanted]
    assert [t for i, t in enumerate(found) if t not in found[:i]] == wanted, texts


def test_home_before_local_position_on_the_real_timeline(target: Target) -> None:
    home, lpn = target.boot["home_s"], target.boot["lpn_s"]
    assert home is not None and lpn is not None, target.boot
    print(f"{target.name}: home at {home:.1f} s, LOCAL_POSITION_NED at {lpn:.1f} s (vehicle clock), "
          f"start-up {target.boot['wall_s']:.1f} s wall at x{target.speedup:g}")
    assert home < lpn
    assert home == pytest.approx(HOME_AT_S, abs=BOOT_TOLERANCE_S)
    assert lpn == pytest.approx(POSITION_AT_S, abs=BOOT_TOLERANCE_S)


def test_interval_set_before_ready_is_lost(target: Target) -> None:
    """Acknowledged, but ArduPilot sets its streams up after start-up: ask again after "ArduPilot Ready"."""
    assert target.boot["early_interval"] == mav.MAV_RESULT_ACCEPTED
    assert target.boot["early_interval_kept"] is False


def test_arming_refused_before_the_ekf_has_a_position(target: Target) -> None:
    assert target.boot["arm_before_position"] == mav.MAV_RESULT_FAILED


# ---------------------------------------------------------------------------- commands on the ground

# (params 1-7 of MAV_CMD_SET_MESSAGE_INTERVAL, result): the rows of REAL_ARDUCOPTER.md and more.
INTERVAL_ROWS = [
    ((32, 100000, NAN, NAN, NAN, NAN, NAN), mav.MAV_RESULT_DENIED),
    ((32, 100000, NAN, NAN, 0, 0, 0), mav.MAV_RESULT_DENIED),
    ((32, 100000, NAN, 0, 0, 0, 0), mav.MAV_RESULT_DENIED),
    ((32, 100000, 0, NAN, 0, 0, 0), mav.MAV_RESULT_ACCEPTED),
    ((32, 100000, 0, 0, NAN, NAN, 0), mav.MAV_RESULT_ACCEPTED),
    ((32, 100000, 0, 0, 0, 0, NAN), mav.MAV_RESULT_ACCEPTED),
    ((32, 100000, 0, 0, 0, 0, 0), mav.MAV_RESULT_ACCEPTED),
    ((33, 100000, 0, 0, 0, 0, 0), mav.MAV_RESULT_ACCEPTED),
    ((85, 100000, 0, 0, 0, 0, 0), mav.MAV_RESULT_ACCEPTED),
    ((30, 100000, 0, 0, 0, 0, 0), mav.MAV_RESULT_ACCEPTED),
    ((32, 0, 0, 0, 0, 0, 0), mav.MAV_RESULT_ACCEPTED),  # 0: default rate
    ((32, -2, 0, 0, 0, 0, 0), mav.MAV_RESULT_DENIED),  # only -1 means "stop"
    ((32, 500, 0, 0, 0, 0, 0), mav.MAV_RESULT_DENIED),  # faster than the loop
    ((32, NAN, 0, 0, 0, 0, 0), mav.MAV_RESULT_DENIED),
    ((9999, 100000, 0, 0, 0, 0, 0), mav.MAV_RESULT_DENIED),  # no such message
    ((32, 100000, 0, 0, 0, 0, 0), mav.MAV_RESULT_ACCEPTED),  # last: leave LOCAL_POSITION_NED at 10 Hz
]


@pytest.mark.parametrize("params,result", INTERVAL_ROWS, ids=[f"row{i}" for i in range(len(INTERVAL_ROWS))])
def test_set_message_interval_answers(link: Link, params: tuple, result: int) -> None:
    assert link.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, *params) == result


@pytest.mark.parametrize("msgid,name", [(242, "HOME_POSITION"), (148, "AUTOPILOT_VERSION")])
def test_request_message(link: Link, msgid: int, name: str) -> None:
    link.drain()
    link.m.mav.command_long_send(1, 1, mav.MAV_CMD_REQUEST_MESSAGE, 0, msgid, NAN, NAN, NAN, NAN, NAN, NAN)
    got: dict = {}
    for _ in range(20):
        msg = link.wait(["COMMAND_ACK", name], sim_s=3.0)
        if msg is None:
            break
        if msg.get_type() == name:
            got["msg"] = msg
        elif msg.command == mav.MAV_CMD_REQUEST_MESSAGE:
            got["ack"] = msg.result
        if len(got) == 2:
            break
    assert got.get("ack") == mav.MAV_RESULT_ACCEPTED and "msg" in got, got
    if name == "HOME_POSITION":
        assert got["msg"].latitude == pytest.approx(473977420, abs=20) and got["msg"].altitude == pytest.approx(488000, abs=500)


def test_request_message_for_an_unknown_message_fails(link: Link) -> None:
    assert link.command(mav.MAV_CMD_REQUEST_MESSAGE, 9999, 0, 0, 0, 0, 0, 0) == mav.MAV_RESULT_FAILED


def test_takeoff_refused_when_disarmed(link: Link) -> None:
    assert _set_mode(link, STABILIZE) == mav.MAV_RESULT_ACCEPTED
    _wait_mode(link, STABILIZE)
    assert link.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, TAKEOFF_ALT_M) == mav.MAV_RESULT_FAILED
    assert _set_mode(link, GUIDED) == mav.MAV_RESULT_ACCEPTED
    _wait_mode(link, GUIDED)
    assert link.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, TAKEOFF_ALT_M) == mav.MAV_RESULT_FAILED


def test_mode_changes_as_ardupilot_answers_them(link: Link) -> None:
    # DO_SET_MODE: base_mode without CUSTOM_MODE_ENABLED is DENIED, an unknown mode FAILED.
    assert link.command(mav.MAV_CMD_DO_SET_MODE, 0, LOITER, 0, 0, 0, 0, 0) == mav.MAV_RESULT_DENIED
    assert _set_mode(link, 99) == mav.MAV_RESULT_FAILED
    # The legacy SET_MODE message: the mode changes, and no COMMAND_ACK comes back.
    link.drain()
    link.m.mav.set_mode_send(1, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, LOITER)
    _wait_mode(link, LOITER)
    assert link.wait("COMMAND_ACK", sim_s=2.0) is None
    assert _set_mode(link, GUIDED) == mav.MAV_RESULT_ACCEPTED
    _wait_mode(link, GUIDED)


def test_param_read_and_set_round_trip(link: Link) -> None:
    def value(name: str):
        return link.wait("PARAM_VALUE", lambda p: p.param_id == name, sim_s=3.0)

    link.m.mav.param_request_read_send(1, 1, b"GUID_TIMEOUT", -1)
    pv = value("GUID_TIMEOUT")
    assert pv is not None and pv.param_value == pytest.approx(3.0) and pv.param_type == mav.MAV_PARAM_TYPE_REAL32
    link.m.mav.param_set_send(1, 1, b"GUID_TIMEOUT", 4.0, mav.MAV_PARAM_TYPE_REAL32)
    assert (pv := value("GUID_TIMEOUT")) is not None and pv.param_value == pytest.approx(4.0)
    link.m.mav.param_request_read_send(1, 1, b"GUID_TIMEOUT", -1)
    assert (pv := value("GUID_TIMEOUT")) is not None and pv.param_value == pytest.approx(4.0)
    link.m.mav.param_set_send(1, 1, b"GUID_TIMEOUT", 3.0, mav.MAV_PARAM_TYPE_REAL32)
    assert (pv := value("GUID_TIMEOUT")) is not None and pv.param_value == pytest.approx(3.0)
    # The 4.7 name of the system id (SYSID_THISMAV before), an INT16.
    link.m.mav.param_request_read_send(1, 1, b"MAV_SYSID", -1)
    assert (pv := value("MAV_SYSID")) is not None and pv.param_value == 1 and pv.param_type == mav.MAV_PARAM_TYPE_INT16
    # An unknown name: silence.
    link.m.mav.param_request_read_send(1, 1, b"NO_SUCH_PARAM", -1)
    assert link.wait("PARAM_VALUE", sim_s=2.0) is None


def test_mavsdk_sees_an_ardupilot_and_reads_its_params(target: Target) -> None:
    """MAVSDK on a second link: discovery, the autopilot's identity and a parameter."""
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.param import ParamAsync

    async def scenario() -> tuple[int, float]:
        cfg = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
        async with Mavsdk(cfg) as sdk:
            await sdk.add_any_connection(target.second_url_mavsdk)
            system = await sdk.first_autopilot(target.wall(10.0))
            assert system is not None, "MAVSDK found no autopilot"
            return await system.get_system_id(), await ParamAsync(system).get_param_float("GUID_TIMEOUT")

    sysid, guid_timeout = asyncio.run(scenario())
    assert sysid == 1 and guid_timeout == pytest.approx(3.0)


# ---------------------------------------------------------------------------- flight


def test_arm_and_takeoff_climb_to_the_target_altitude(link: Link) -> None:
    assert _set_mode(link, GUIDED) == mav.MAV_RESULT_ACCEPTED
    assert link.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1, 0, 0, 0, 0, 0, 0) == mav.MAV_RESULT_ACCEPTED
    assert link.wait("HEARTBEAT", lambda h: h.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED, sim_s=3.0) is not None
    assert link.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, TAKEOFF_ALT_M) == mav.MAV_RESULT_ACCEPTED
    peak = 0.0

    def settled(p) -> bool:  # at the target altitude and no longer climbing
        nonlocal peak
        peak = max(peak, -p.z)
        return abs(-p.z - TAKEOFF_ALT_M) < 0.5 and abs(p.vz) < 0.3

    top = link.wait("LOCAL_POSITION_NED", settled, sim_s=40.0)
    assert top is not None, f"did not settle at the takeoff altitude (peak {peak:.2f} m)"
    print(f"{link.target.name}: takeoff peak {peak:.2f} m, settled at {-top.z:.2f} m, t={top.time_boot_ms / 1000:.1f} s")


def test_disarm_in_the_air_fails(link: Link) -> None:
    assert link.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0, 0, 0, 0, 0, 0) == mav.MAV_RESULT_FAILED


def test_acceleration_setpoint_is_accepted_and_echoed(link: Link) -> None:
    assert link.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, 85, 100_000, 0, 0, 0, 0, 0) == mav.MAV_RESULT_ACCEPTED
    echo = None
    for _ in range(40):
        link.m.mav.set_position_target_local_ned_send(0, 1, 1, mav.MAV_FRAME_LOCAL_NED, ACCEL_ONLY,
                                                      0, 0, 0, 0, 0, 0, 0.5, 0, 0, 0, 0)
        echo = link.wait("POSITION_TARGET_LOCAL_NED", lambda t: t.type_mask == ACCEL_ONLY, sim_s=0.5) or echo
        if echo is not None and echo.afx == pytest.approx(0.5):
            break
    assert echo is not None, "no POSITION_TARGET_LOCAL_NED with the acceleration-only mask"
    assert echo.coordinate_frame == mav.MAV_FRAME_LOCAL_NED and (echo.afx, echo.afy, echo.afz) == pytest.approx((0.5, 0, 0))
    for _ in range(5):  # stop: zero acceleration, then let GUID_TIMEOUT brake it
        link.m.mav.set_position_target_local_ned_send(0, 1, 1, mav.MAV_FRAME_LOCAL_NED, ACCEL_ONLY,
                                                      0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0)


def test_land_then_disarm(link: Link) -> None:
    assert link.command(mav.MAV_CMD_NAV_LAND, 0, 0, 0, NAN, NAN, NAN, NAN) == mav.MAV_RESULT_ACCEPTED
    _wait_mode(link, LAND)
    hb = link.wait("HEARTBEAT", lambda h: not h.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED, sim_s=90.0)
    assert hb is not None, "still armed"
    assert hb.custom_mode == LAND
    if "Disarming motors" not in [t for _, t in link.texts]:  # the real one says it first, we just after
        assert link.wait("STATUSTEXT", lambda t: t.text == "Disarming motors", sim_s=2.0) is not None
    pos = link.wait("LOCAL_POSITION_NED", sim_s=2.0)
    assert pos is not None and abs(pos.z) < 0.3
