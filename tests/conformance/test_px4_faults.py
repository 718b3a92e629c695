"""Differential conformance of autopilot faults: the same pymavlink checks against the
emulator's PX4 personality and, with PX4_SITL set, a real PX4 SITL (SIH quadrotor), through
PX4's own fault injection as the SITL world gives it (sitl/px4.py): the GPS by SIH's
SIM_GPS_USED (0: no fix), a motor by MAV_CMD_INJECT_FAILURE.

The expected values are what the real PX4 did (docs/CONFORMANCE.md, "Autopilot faults"), in
file order on one vehicle per target: in OFFBOARD under acceleration setpoints, a GPS loss
changes nothing (the mode, arming, the position stream); once the setpoints stop, the
failsafe cannot hold a position and takes ALTCTL (CRITICAL); the GPS back, AUTO.RTL; a motor
stopped, the vehicle says so and falls, armed. Times are vehicle seconds.
"""

from __future__ import annotations

import math
import struct
import time

import pytest
from pymavlink import mavutil

from conformance.link import Link
from conformance.targets import Target

pytestmark = [pytest.mark.integration, pytest.mark.conformance, pytest.mark.timeout(400)]

mav = mavutil.mavlink
NAN = math.nan
ACCEL_ONLY = 0x0C3F
OFFBOARD, ALTCTL, LOITER, RTL = 6 << 16, 2 << 16, (4 << 16) | (3 << 24), (4 << 16) | (5 << 24)
TAKEOFF_ALT_M = 30.0


def _accel(link: Link) -> None:
    link.m.mav.set_position_target_local_ned_send(0, link.sysid, 1, mav.MAV_FRAME_LOCAL_NED, ACCEL_ONLY,
                                                  0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0)


def _follow(link: Link, sim_s: float, stream: bool, seen: list | None = None) -> None:
    """`sim_s` vehicle seconds, streaming zero-acceleration setpoints at ~20 Hz (as the agent
    streams its own) or not; `seen` collects every message."""
    until = link.clock_s + sim_s
    end = time.monotonic() + link.target.wall(sim_s) + 5
    last = -1.0
    while link.clock_s < until and time.monotonic() < end:
        if stream and (link.clock_s - last >= 0.05 or last < 0):
            _accel(link)
            last = link.clock_s
        msg = link.recv(0.02)
        if msg is not None and seen is not None:
            seen.append((link.clock_s, msg))


def _gps(link: Link, satellites: int) -> bool:
    """PARAM_SET SIM_GPS_USED (INT32, bytewise as PX4 puts it on the wire); echoed?"""
    value = struct.unpack("<f", struct.pack("<i", satellites))[0]
    for _ in range(3):
        link.m.mav.param_set_send(link.sysid, 1, b"SIM_GPS_USED", value, mav.MAV_PARAM_TYPE_INT32)
        if link.wait("PARAM_VALUE", lambda p: p.param_id == "SIM_GPS_USED" and p.param_value == value, sim_s=2.0):
            return True
    return False


def _modes(seen: list) -> list[tuple[float, int, int, bool]]:
    return [(t, m.custom_mode, m.system_status, bool(m.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED))
            for t, m in seen if m.get_type() == "HEARTBEAT"]


def test_offboard_under_acceleration_setpoints(px4_link: Link, px4_target: Target) -> None:
    """The agent's way up: take-off (param7 AMSL), AUTO.LOITER, the stream, OFFBOARD."""
    px4_link.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, mav.MAVLINK_MSG_ID_GPS_RAW_INT, 500_000, 0, 0, 0, 0, 0)
    home_amsl = px4_target.boot["home"].altitude / 1000
    assert px4_link.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, NAN, NAN, home_amsl + TAKEOFF_ALT_M) == mav.MAV_RESULT_ACCEPTED
    assert px4_link.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1, 0, 0, 0, 0, 0, 0) == mav.MAV_RESULT_ACCEPTED
    assert px4_link.wait("HEARTBEAT", lambda h: h.custom_mode == LOITER, sim_s=60.0) is not None
    _follow(px4_link, 1.0, stream=True)
    assert px4_link.command(mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 6, 0, 0, 0, 0, 0) == mav.MAV_RESULT_ACCEPTED
    seen: list = []
    _follow(px4_link, 3.0, stream=True, seen=seen)
    assert _modes(seen) and _modes(seen)[-1][1:] == (OFFBOARD, mav.MAV_STATE_ACTIVE, True), _modes(seen)


def test_gps_loss_under_acceleration_setpoints_changes_nothing(px4_link: Link, px4_target: Target) -> None:
    """SIM_GPS_USED 0: no fix (GPS_RAW_INT); 20 s on, still OFFBOARD, ACTIVE, armed, with no
    STATUSTEXT, and LOCAL_POSITION_NED never stops (OFFBOARD with acceleration needs only an
    attitude: commander offboardCheck.cpp). ArduCopter lands 8 s into a GPS loss."""
    assert _gps(px4_link, 0)
    lost = px4_link.clock_s
    seen: list = []
    _follow(px4_link, 20.0, stream=True, seen=seen)
    modes = {m[1:] for m in _modes(seen)}
    assert modes == {(OFFBOARD, mav.MAV_STATE_ACTIVE, True)}, modes
    assert not [t for t, text in px4_link.texts if t > lost], px4_link.texts[-5:]
    lpn = [t for t, m in seen if m.get_type() == "LOCAL_POSITION_NED"]
    assert lpn and lpn[-1] > lost + 19 and max(b - a for a, b in zip(lpn, lpn[1:], strict=False)) < 1.0
    fixes = [m.fix_type for t, m in seen if m.get_type() == "GPS_RAW_INT" and t > lost + 1.0]
    assert fixes and max(fixes) < mav.GPS_FIX_TYPE_2D_FIX, fixes
    px4_target.boot["gps_loss_modes"] = sorted(modes)


def test_setpoint_loss_without_gps_takes_altctl_then_rtl_with_gps(px4_link: Link, px4_target: Target) -> None:
    """The setpoints stop (COM_OF_LOSS_T 1 s): "Failsafe activated" ~1 s later, and with no
    position to hold or return by, ALTCTL, CRITICAL (measured: the text at 1.02 s, ALTCTL
    in the next heartbeat). The GPS back: "Failsafe activated" and AUTO.RTL (measured 2.3 s)."""
    stopped = px4_link.clock_s
    seen: list = []
    _follow(px4_link, 6.0, stream=False, seen=seen)
    text = next((t for t, x in px4_link.texts if t >= stopped and "Failsafe activated" in x), None)
    assert text is not None, px4_link.texts[-5:]
    px4_target.boot["no_gps_failsafe_after_s"] = round(text - stopped, 2)
    assert 0.5 <= text - stopped <= 2.5, text - stopped
    after = [m for m in _modes(seen) if m[0] > text + 1.1]
    assert after and {m[1:] for m in after} == {(ALTCTL, mav.MAV_STATE_CRITICAL, True)}, _modes(seen)
    assert _gps(px4_link, 10)
    back = px4_link.clock_s
    seen = []
    _follow(px4_link, 6.0, stream=False, seen=seen)
    rtl = next((t for t, c, _, _ in _modes(seen) if c == RTL), None)
    assert rtl is not None, (_modes(seen), px4_link.texts[-5:])
    px4_target.boot["gps_back_rtl_after_s"] = round(rtl - back, 2)
    assert rtl - back <= 5.0


def test_motor_failure_says_so_and_falls_armed(px4_link: Link, px4_target: Target) -> None:
    """MAV_CMD_INJECT_FAILURE motor 1 off: ACCEPTED; "Attitude failure (roll)" ~0.8 s later;
    it falls (measured ~8 m/s, bounded by SIH's drag) and stays armed in its mode."""
    seen: list = []
    _follow(px4_link, 2.0, stream=False, seen=seen)
    alt0 = next(-m.z for t, m in reversed(seen) if m.get_type() == "LOCAL_POSITION_NED")
    since = px4_link.clock_s
    assert px4_link.command(mav.MAV_CMD_INJECT_FAILURE, mav.FAILURE_UNIT_SYSTEM_MOTOR, mav.FAILURE_TYPE_OFF, 1,
                            0, 0, 0, 0) == mav.MAV_RESULT_ACCEPTED
    seen = []
    _follow(px4_link, 4.0, stream=False, seen=seen)
    # (it may come before the COMMAND_ACK: the link keeps every STATUSTEXT)
    text = next((t for t, x in px4_link.texts if t >= since and "Attitude failure" in x), None)
    assert text is not None and text - since <= 2.5, px4_link.texts[-5:]
    alts = [(t, -m.z) for t, m in seen if m.get_type() == "LOCAL_POSITION_NED"]
    # Real: ~24 m in 4 s; the emulator falls within the mission's vehicle model (5 m/s^2, its
    # vertical speed limit), ~5 m (docs/CONFORMANCE.md, "known and kept").
    assert alts[-1][1] < alt0 - 3.0, (alt0, alts[-3:])
    assert _modes(seen) and all(armed for *_, armed in _modes(seen))
    px4_target.boot["motor_text_after_s"] = round(text - since, 2)
    px4_target.boot["fall_m_in_4s"] = round(alt0 - alts[-1][1], 1)
