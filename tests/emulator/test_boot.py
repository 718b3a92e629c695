"""Start-up of the emulator: instant, or on ArduCopter's measured timeline (`--boot real`).

Driven through the real message path without sockets (see test_host.Client), in exact sim time.
"""

from __future__ import annotations

import math

import pytest
from test_host import Client

from plmarl_sitl.deploy.mavlink.codec import dialect
from plmarl_sitl.deploy.mavlink.personality import personality
from plmarl_sitl.errors import UserError
from plmarl_sitl.sitl.autopilot import AutopilotHost

d = dialect
TL = personality("ardupilot").boot_timeline
assert TL is not None


def _types(c: Client) -> list[str]:
    return [m.get_type() for m in c.sent]


def _texts(c: Client) -> list[str]:
    return [m.text for m in c.sent if m.get_type() == "STATUSTEXT"]


def test_real_boot_follows_the_measured_timeline() -> None:
    host = AutopilotHost(1, personality_name="ardupilot", boot="real")
    c = Client(host, 0)
    c.v.peers[("127.0.0.1", 9)] = None
    host.advance(1.0)
    hb = [m for m in c.sent if m.get_type() == "HEARTBEAT"]
    assert hb and hb[-1].system_status == d.MAV_STATE_BOOT and hb[-1].autopilot == d.MAV_AUTOPILOT_ARDUPILOTMEGA
    host.advance(TL.origin_s - 1.0 - 0.1)
    assert "HOME_POSITION" not in _types(c) and "LOCAL_POSITION_NED" not in _types(c)
    assert _texts(c) == ["ArduPilot Ready", "EKF3 IMU0 initialised", "AHRS: EKF3 active"]
    # Home exists only with the EKF origin: until then asked for, it is not sent (ArduPilot accepts and queues).
    assert c.command(d.MAV_CMD_REQUEST_MESSAGE, d.MAVLINK_MSG_ID_HOME_POSITION) == d.MAV_RESULT_ACCEPTED
    assert c.command(d.MAV_CMD_GET_HOME_POSITION) == d.MAV_RESULT_FAILED
    assert "HOME_POSITION" not in _types(c)
    c.sent.clear()
    host.advance(0.2)
    assert {"HOME_POSITION", "GPS_GLOBAL_ORIGIN"} <= set(_types(c)) and _texts(c) == ["EKF3 IMU0 origin set"]
    # No position yet: arming in GUIDED is refused, as the real one does ("Need Position Estimate").
    assert c.mode("GUIDED") == d.MAV_RESULT_ACCEPTED
    assert c.command(d.MAV_CMD_COMPONENT_ARM_DISARM, 1) == d.MAV_RESULT_FAILED
    assert "Arm: Need Position Estimate" in _texts(c)
    host.advance(TL.position_s - host.now - 0.1)
    assert "LOCAL_POSITION_NED" not in _types(c)
    host.advance(0.3)
    assert "LOCAL_POSITION_NED" in _types(c) and "EKF3 IMU0 is using GPS" in _texts(c)
    assert c.command(d.MAV_CMD_COMPONENT_ARM_DISARM, 1) == d.MAV_RESULT_ACCEPTED


def test_real_boot_allows_arming_without_position_only_where_no_position_is_needed() -> None:
    host = AutopilotHost(1, personality_name="ardupilot", boot="real")
    c = Client(host, 0)
    host.advance(1.0)
    assert c.command(d.MAV_CMD_COMPONENT_ARM_DISARM, 1) == d.MAV_RESULT_FAILED  # EKF not started
    host.advance(TL.attitude_s)
    assert c.v.mode == "STABILIZE"
    assert c.command(d.MAV_CMD_COMPONENT_ARM_DISARM, 1) == d.MAV_RESULT_ACCEPTED
    # Armed without a position: GUIDED is refused.
    assert c.mode("GUIDED") == d.MAV_RESULT_FAILED and c.v.mode == "STABILIZE"


def test_instant_boot_is_ready_at_once() -> None:
    host = AutopilotHost(1, personality_name="ardupilot")
    c = Client(host, 0)
    c.v.peers[("127.0.0.1", 9)] = None
    host.advance(0.2)
    assert "LOCAL_POSITION_NED" in _types(c) and not _texts(c)
    assert c.mode("GUIDED") == d.MAV_RESULT_ACCEPTED
    assert c.command(d.MAV_CMD_COMPONENT_ARM_DISARM, 1) == d.MAV_RESULT_ACCEPTED


def test_boot_real_names_only_known_timelines() -> None:
    # Both personalities have a measured start-up now (PX4's: issue 28, docs/CONFORMANCE.md).
    assert AutopilotHost(1, personality_name="px4", boot="real").fleet.boot.timeline is not None
    with pytest.raises(UserError, match="--boot must be one of"):
        AutopilotHost(1, personality_name="ardupilot", boot="late")


@pytest.mark.parametrize(
    "params,result",
    [
        # The rows measured on ArduCopter 4.7 (docs/CONFORMANCE.md): param3 is reserved, must be 0.
        ((32, 100000, math.nan, math.nan, math.nan, math.nan, math.nan), d.MAV_RESULT_DENIED),
        ((32, 100000, math.nan, math.nan, 0, 0, 0), d.MAV_RESULT_DENIED),
        ((32, 100000, 0, 0, 0, 0, math.nan), d.MAV_RESULT_ACCEPTED),
        ((32, 100000, 0, math.nan, 0, 0, 0), d.MAV_RESULT_ACCEPTED),
        ((32, 100000, 0, 0, 0, 0, 0), d.MAV_RESULT_ACCEPTED),
        ((32, -1, 0, 0, 0, 0, 0), d.MAV_RESULT_ACCEPTED),
        ((32, -2, 0, 0, 0, 0, 0), d.MAV_RESULT_DENIED),
        ((9999, 100000, 0, 0, 0, 0, 0), d.MAV_RESULT_DENIED),
    ],
)
def test_ardupilot_set_message_interval_answers(params: tuple, result: int) -> None:
    c = Client(AutopilotHost(1, personality_name="ardupilot"), 0)
    assert c.command(d.MAV_CMD_SET_MESSAGE_INTERVAL, *params) == result


def test_ardupilot_takeoff_and_mode_answers() -> None:
    c = Client(AutopilotHost(1, personality_name="ardupilot"), 0)
    nan = math.nan
    assert c.command(d.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, nan, nan, nan, 10) == d.MAV_RESULT_FAILED  # disarmed, STABILIZE
    assert c.command(d.MAV_CMD_DO_SET_MODE, 0, 4) == d.MAV_RESULT_DENIED  # no CUSTOM_MODE flag
    assert c.command(d.MAV_CMD_DO_SET_MODE, 1, 99) == d.MAV_RESULT_FAILED  # no such mode
    assert c.mode("GUIDED") == d.MAV_RESULT_ACCEPTED
    assert c.command(d.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, nan, nan, nan, 10) == d.MAV_RESULT_FAILED  # disarmed, GUIDED
    assert c.command(d.MAV_CMD_COMPONENT_ARM_DISARM, 1) == d.MAV_RESULT_ACCEPTED
    assert c.command(d.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, nan, nan, nan, 0) == d.MAV_RESULT_FAILED  # downwards
    acks = len(c.acks)
    c.feed(c.codec.mav.set_mode_encode(1, 1, 5))  # legacy SET_MODE: no COMMAND_ACK from ArduPilot 4.7
    assert len(c.acks) == acks and c.v.mode == "LOITER"
