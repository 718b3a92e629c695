"""Autopilot faults on the emulator, seen by a real MAVLink client over real UDP.

The ArduPilot personality must react to a GPS loss and a motor failure as a real
ArduCopter 4.7 SITL was measured to (docs/RESULTS.md, "Autopilot faults"): GPS gone in
GUIDED flight, the EKF failsafe switches to LAND 8 s later, LOCAL_POSITION_NED stops 15 s
later, the vehicle lands and disarms, and the stream resumes (still in LAND) when the GPS
is back; one motor gone, it falls, hits the ground and stays armed in GUIDED. Every time
is read on the vehicle's clock (time_boot_ms), so the checks hold at any speedup.
"""

from __future__ import annotations

import asyncio
import math
import time

import pytest
from aphelpers import run, running_host
from pymavlink import mavutil

from plmarl_sitl.model.events import GPS_AIDING_STOPS_S, GPS_FAILSAFE_S

pytestmark = [pytest.mark.integration, pytest.mark.timeout(120)]
mav = mavutil.mavlink
ACCEL_ONLY = 0x0C3F
GUIDED, LAND = 4, 9


class Client:
    """pymavlink on the vehicle's port, keeping the vehicle clock from every stamped message."""

    def __init__(self, port: int) -> None:
        self.m = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255, source_component=190)
        self.m.mav.heartbeat_send(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        assert self.m.wait_heartbeat(timeout=5) is not None
        self.boot_s = 0.0
        self.log: list[tuple[float, str, object]] = []  # (boot s, kind, value)

    def recv(self, timeout: float = 0.5):
        msg = self.m.recv_match(blocking=True, timeout=timeout)
        if msg is None:
            return None
        if getattr(msg, "time_boot_ms", None) is not None:
            self.boot_s = msg.time_boot_ms / 1000
        t = msg.get_type()
        if t == "STATUSTEXT":
            self.log.append((self.boot_s, "text", msg.text))
        elif t == "LOCAL_POSITION_NED":
            self.log.append((self.boot_s, "lpn", -msg.z))
        elif t == "HEARTBEAT" and msg.get_srcComponent() == 1:
            self.log.append((self.boot_s, "mode", (msg.custom_mode, bool(msg.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED))))
        return msg

    def command(self, cmd: int, *params: float) -> int:
        p = list(params) + [0.0] * (7 - len(params))
        self.m.mav.command_long_send(self.m.target_system, 1, cmd, 0, *p)
        deadline = time.monotonic() + 3
        while time.monotonic() < deadline:
            ack = self.recv()
            if ack is not None and ack.get_type() == "COMMAND_ACK" and ack.command == cmd:
                return ack.result
        raise AssertionError(f"no COMMAND_ACK for {cmd}")

    def fly_until(self, cond, wall_s: float, stream: bool = True) -> None:
        """Stream zero-acceleration setpoints (as the agent streams its own) until cond()."""
        deadline = time.monotonic() + wall_s
        while not cond():
            assert time.monotonic() < deadline, self.log[-20:]
            if stream:
                self.m.mav.set_position_target_local_ned_send(0, self.m.target_system, 1, mav.MAV_FRAME_LOCAL_NED,
                                                              ACCEL_ONLY, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0)
            end = time.monotonic() + 0.05
            while time.monotonic() < end:
                self.recv(0.02)

    def take_off(self, alt_m: float) -> None:
        self.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, mav.MAVLINK_MSG_ID_ATTITUDE, 100_000)  # a clock while LPN is off
        assert self.command(mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, GUIDED) == mav.MAV_RESULT_ACCEPTED
        assert self.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mav.MAV_RESULT_ACCEPTED
        assert self.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, 0, 0, alt_m) == mav.MAV_RESULT_ACCEPTED
        self.fly_until(lambda: self.alt() > alt_m - 0.5, 30, stream=False)  # the agent too waits for the climb

    def alt(self) -> float:
        return next((v for _, k, v in reversed(self.log) if k == "lpn"), 0.0)  # type: ignore[return-value]

    def mode(self) -> tuple[int, bool]:
        return next(v for _, k, v in reversed(self.log) if k == "mode")  # type: ignore[return-value]

    def first(self, kind: str, value=None, after: float = 0.0) -> float | None:
        return next((t for t, k, v in self.log if k == kind and t >= after and (value is None or v == value)), None)


def _with_client(body):
    async def main():
        async with running_host(1, speedup=8.0, personality_name="ardupilot") as host:
            await asyncio.to_thread(lambda: body(host, Client(host.ports[0])))  # off the host's loop

    run(main())


def test_gps_loss_failsafe_lands_then_stream_stops_and_resumes_as_on_arducopter():
    def body(host, c: Client) -> None:
        c.take_off(30.0)
        host.set_gps(0, False)  # the world calls it from its loop; host state is plain Python
        t_loss = host.now  # on the vehicle clock (the client's view may lag on a busy machine)
        c.fly_until(lambda: c.mode() == (LAND, False), 60)  # landed blind and disarmed
        t_fs = c.first("text", "EKF Failsafe: changed to LAND Mode", t_loss)
        t_land = c.first("mode", (LAND, True), t_loss)
        assert t_fs is not None and t_land is not None, c.log
        assert GPS_FAILSAFE_S - 0.5 <= t_fs - t_loss <= GPS_FAILSAFE_S + 0.5
        assert abs(t_land - t_fs) < 0.5
        last_lpn = max(t for t, k, _ in c.log if k == "lpn")
        assert GPS_AIDING_STOPS_S - 0.5 <= last_lpn - t_loss <= GPS_AIDING_STOPS_S + 0.5
        assert c.first("text", "EKF3 IMU0 stopped aiding", t_loss) is not None
        assert c.alt() > 5.0  # the last position it reported was in the air: it landed without one
        t_back = c.boot_s  # a mark on the client's view of the clock, for the messages that follow
        host.set_gps(0, True)
        c.fly_until(lambda: c.first("lpn", after=t_back + 0.2) is not None, 10)
        assert c.first("text", "EKF Failsafe Cleared", t_back) is not None
        assert c.mode() == (LAND, False) and c.alt() < 0.5

    _with_client(body)


def test_a_short_gps_loss_is_bridged_by_dead_reckoning():
    def body(host, c: Client) -> None:
        c.take_off(20.0)
        host.set_gps(0, False)
        t_loss = host.now
        c.fly_until(lambda: c.boot_s > t_loss + GPS_FAILSAFE_S - 2, 30)
        host.set_gps(0, True)
        c.fly_until(lambda: c.boot_s > t_loss + GPS_AIDING_STOPS_S + 2, 30)
        assert c.mode() == (GUIDED, True)
        assert not [v for t, k, v in c.log if k == "text" and t >= t_loss], c.log
        gaps = [b - a for (a, k1, _), (b, k2, _) in zip(c.log, c.log[1:], strict=False) if k1 == k2 == "lpn"]
        assert max(gaps) < 1.0  # LOCAL_POSITION_NED never stopped

    _with_client(body)


def test_motor_failure_falls_and_stays_armed_where_it_crashed():
    def body(host, c: Client) -> None:
        c.take_off(30.0)
        host.fail_motor(0)
        t_fail = host.now
        c.fly_until(lambda: c.first("text", "SIM Hit ground", t_fail) is not None, 30)
        t_hit = c.first("text", "SIM Hit ground", t_fail)
        assert t_hit is not None and t_hit - t_fail < 4.0  # measured: 3.3 s from 30 m
        c.fly_until(lambda: c.boot_s > t_hit + 5, 20)  # the agent's setpoints cannot lift it
        assert c.alt() < 0.5
        assert c.mode() == (GUIDED, True)

    _with_client(body)


# ---------------------------------------------------------------------------- PX4
# The PX4 personality as a real PX4 1.17 SIH was measured to react under a stream of
# acceleration setpoints (docs/CONFORMANCE.md, "Autopilot faults"): a GPS loss changes
# nothing (OFFBOARD with acceleration setpoints needs only an attitude), the position stream
# goes on; once the setpoints stop, its failsafe cannot hold a position and takes ALTCTL
# (CRITICAL); the GPS back, AUTO.RTL.
OFFBOARD, ALTCTL, LOITER, RTL = 6 << 16, 2 << 16, (4 << 16) | (3 << 24), (4 << 16) | (5 << 24)


def _px4_with_client(body):
    async def main():
        async with running_host(1, speedup=4.0, personality_name="px4") as host:
            await asyncio.to_thread(lambda: body(host, Client(host.ports[0])))

    run(main())


def _px4_offboard(host, c: Client, alt_m: float) -> None:
    c.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, mav.MAVLINK_MSG_ID_GPS_RAW_INT, 200_000)
    # COM_OF_LOSS_T 3 s: at 4x the default 1 s is 0.25 s of wall time, which a loaded machine's
    # client loop can miss (a setpoint loss the test did not mean)
    c.m.mav.param_set_send(c.m.target_system, 1, b"COM_OF_LOSS_T", 3.0, mav.MAV_PARAM_TYPE_REAL32)
    amsl = host.vehicles[0].home_geodetic[2] + alt_m  # PX4: NAV_TAKEOFF param7 is AMSL
    assert c.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, amsl) == mav.MAV_RESULT_ACCEPTED
    assert c.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mav.MAV_RESULT_ACCEPTED
    c.fly_until(lambda: c.mode() == (LOITER, True), 60, stream=False)
    t = c.boot_s
    c.fly_until(lambda: c.boot_s > t + 1.0, 10)  # the stream first: PX4 refuses OFFBOARD without one
    assert c.command(mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 6) == mav.MAV_RESULT_ACCEPTED
    c.fly_until(lambda: c.mode() == (OFFBOARD, True), 10)


def test_px4_gps_loss_under_acceleration_setpoints_changes_nothing():
    def body(host, c: Client) -> None:
        _px4_offboard(host, c, 20.0)
        fixes: list[int] = []
        host.set_gps(0, False)
        t_loss = host.now
        c.fly_until(lambda: c.boot_s > t_loss + 20, 40)  # longer than ArduCopter's 8 s and 15 s
        assert c.mode() == (OFFBOARD, True)
        assert not [v for t, k, v in c.log if k == "text" and t >= t_loss], c.log
        lpn = [t for t, k, _ in c.log if k == "lpn" and t >= t_loss]
        assert lpn and max(b - a for a, b in zip(lpn, lpn[1:], strict=False)) < 1.0  # streamed on
        while (m := c.m.recv_match(type="GPS_RAW_INT", blocking=True, timeout=2)) is not None and len(fixes) < 2:
            fixes.append(m.fix_type)
        assert fixes and set(fixes) == {mav.GPS_FIX_TYPE_NO_GPS}, fixes

    _px4_with_client(body)


def test_px4_setpoint_loss_without_gps_takes_altctl_then_rtl_when_it_is_back():
    def body(host, c: Client) -> None:
        _px4_offboard(host, c, 20.0)
        host.set_gps(0, False)
        t = c.boot_s
        c.fly_until(lambda: c.boot_s > t + 2.0, 10)
        t_stop = c.boot_s
        c.fly_until(lambda: c.mode() == (ALTCTL, True), 10, stream=False)  # measured: 1.0 s (COM_OF_LOSS_T 1), then ALTCTL
        assert c.first("text", "Failsafe activated", t_stop) is not None
        hb = c.m.recv_match(type="HEARTBEAT", blocking=True, timeout=3)
        assert hb is not None and hb.system_status == mav.MAV_STATE_CRITICAL
        alt = c.alt()
        c.fly_until(lambda: c.boot_s > t_stop + 10, 10, stream=False)
        assert c.mode() == (ALTCTL, True) and abs(c.alt() - alt) < 2.0  # holds its altitude
        t_back = c.boot_s
        host.set_gps(0, True)
        c.fly_until(lambda: c.mode() == (RTL, True), 10, stream=False)
        assert c.first("text", "Failsafe activated", t_back) is not None

    _px4_with_client(body)
