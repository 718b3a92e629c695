"""pymavlink (mavutil, a real client) against the ArduPilot personality over real UDP.

Runs at 4x speed: every time check uses the vehicle's clock (time_boot_ms), which is sim
time, so the checks are exactly as strict as at 1x.
"""

from __future__ import annotations

import asyncio
import math
import time

import pytest
from aphelpers import run, running_host
from pymavlink import mavutil

pytestmark = [pytest.mark.integration, pytest.mark.timeout(90)]

ACCEL_ONLY = 0x0C3F


def _connect(port: int) -> mavutil.mavfile:
    m = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255, source_component=190)
    m.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
    hb = m.wait_heartbeat(timeout=5)
    assert hb is not None, "no heartbeat"
    return m


def _command(m: mavutil.mavfile, cmd: int, *params: float) -> int:
    p = list(params) + [0.0] * (7 - len(params))
    m.mav.command_long_send(m.target_system, 1, cmd, 0, *p)
    deadline = time.monotonic() + 3
    while time.monotonic() < deadline:
        ack = m.recv_match(type="COMMAND_ACK", blocking=True, timeout=0.5)
        if ack is not None and ack.command == cmd:
            return ack.result
    raise AssertionError(f"no COMMAND_ACK for {cmd}")


def _wait(m: mavutil.mavfile, mtype: str, cond=lambda msg: True, timeout: float = 10.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        msg = m.recv_match(type=mtype, blocking=True, timeout=0.5)
        if msg is not None and cond(msg):
            return msg
    raise AssertionError(f"no matching {mtype} within {timeout} s")


def _request(m: mavutil.mavfile, msgid: int, name: str):
    """MAV_CMD_REQUEST_MESSAGE: expect the message and an ACCEPTED ack, in either order."""
    m.mav.command_long_send(m.target_system, 1, mavutil.mavlink.MAV_CMD_REQUEST_MESSAGE, 0, msgid, 0, 0, 0, 0, 0, 0)
    got, acked = None, False
    deadline = time.monotonic() + 3
    while time.monotonic() < deadline and not (got and acked):
        msg = m.recv_match(type=["COMMAND_ACK", name], blocking=True, timeout=0.5)
        if msg is None:
            continue
        if msg.get_type() == name:
            got = msg
        elif msg.command == mavutil.mavlink.MAV_CMD_REQUEST_MESSAGE:
            assert msg.result == mavutil.mavlink.MAV_RESULT_ACCEPTED
            acked = True
    assert got is not None and acked, f"REQUEST_MESSAGE {name}: message {got is not None}, ack {acked}"
    return got


def _accel(m: mavutil.mavfile, ax: float, ay: float, az: float) -> None:
    m.mav.set_position_target_local_ned_send(
        0, m.target_system, 1, mavutil.mavlink.MAV_FRAME_LOCAL_NED, ACCEL_ONLY, 0, 0, 0, 0, 0, 0, ax, ay, az, 0, 0
    )


def _flight(port: int) -> dict:
    m = _connect(port)
    mav = mavutil.mavlink
    hb = _wait(m, "HEARTBEAT", lambda h: h.get_srcComponent() == 1)
    assert (hb.autopilot, hb.type, m.target_system) == (mav.MAV_AUTOPILOT_ARDUPILOTMEGA, mav.MAV_TYPE_QUADROTOR, 3)

    # Mode by MAV_CMD_DO_SET_MODE, as pymavlink/MAVSDK do for ArduPilot: GUIDED = 4.
    assert _command(m, mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4) == mav.MAV_RESULT_ACCEPTED
    _wait(m, "HEARTBEAT", lambda h: h.custom_mode == 4)
    assert _command(m, mav.MAV_CMD_COMPONENT_ARM_DISARM, 1) == mav.MAV_RESULT_ACCEPTED
    _wait(m, "HEARTBEAT", lambda h: h.base_mode & mav.MAV_MODE_FLAG_SAFETY_ARMED)
    assert _command(m, mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, 0, 0, 10.0) == mav.MAV_RESULT_ACCEPTED
    _wait(m, "LOCAL_POSITION_NED", lambda p: abs(p.z + 10.0) < 0.3 and abs(p.vz) < 0.2, timeout=20)
    # Disarming in the air is refused unless forced (ArduCopter 4.7 answers FAILED, measured).
    assert _command(m, mav.MAV_CMD_COMPONENT_ARM_DISARM, 0) == mav.MAV_RESULT_FAILED

    # Accelerate east at 1 m/s^2, then zero acceleration (= keep velocity), then stop streaming.
    end = time.monotonic() + 1.5
    while time.monotonic() < end:
        _accel(m, 0.0, 1.0, 0.0)
        time.sleep(0.05)
    end = time.monotonic() + 0.5
    while time.monotonic() < end:
        _accel(m, 0.0, 0.0, 0.0)
        time.sleep(0.05)
    while m.recv_match(blocking=False) is not None:
        pass  # drop telemetry queued while we were streaming
    last = _wait(m, "LOCAL_POSITION_NED")
    t_last, v0 = last.time_boot_ms / 1000, last.vy
    samples = []
    while True:
        p = _wait(m, "LOCAL_POSITION_NED")
        samples.append((p.time_boot_ms / 1000 - t_last, p.vy))
        if samples[-1][0] > 9.0:
            break
    hb = _wait(m, "HEARTBEAT", lambda h: h.get_srcComponent() == 1)
    out = {"v0": v0, "samples": samples, "mode_after": hb.custom_mode}

    # Parameters: list, then a set round trip.
    m.mav.param_request_list_send(m.target_system, 1)
    params = {}
    while len(params) < 7:
        pv = _wait(m, "PARAM_VALUE", timeout=3)
        params[pv.param_id] = (pv.param_value, pv.param_count)
    out["params"] = params
    m.mav.param_set_send(m.target_system, 1, b"GUID_TIMEOUT", 2.5, mav.MAV_PARAM_TYPE_REAL32)
    out["param_set"] = _wait(m, "PARAM_VALUE", lambda p: p.param_id == "GUID_TIMEOUT", timeout=3).param_value
    m.mav.param_request_read_send(m.target_system, 1, b"GUID_TIMEOUT", -1)
    out["param_read"] = _wait(m, "PARAM_VALUE", lambda p: p.param_id == "GUID_TIMEOUT", timeout=3).param_value

    m.mav.mission_request_list_send(m.target_system, 1)
    out["mission_count"] = _wait(m, "MISSION_COUNT", timeout=3).count
    out["unknown_cmd"] = _command(m, mav.MAV_CMD_USER_1)
    out["version"] = _request(m, mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION, "AUTOPILOT_VERSION")
    out["home"] = _request(m, mav.MAVLINK_MSG_ID_HOME_POSITION, "HOME_POSITION")
    m.mav.timesync_send(0, 123456)
    out["timesync"] = _wait(m, "TIMESYNC", lambda t: t.ts1 == 123456, timeout=3)
    out["system_time"] = _wait(m, "SYSTEM_TIME", timeout=5)
    m.close()
    return out


def test_pymavlink_guided_flight_params_mission() -> None:
    async def scenario() -> tuple[dict, object]:
        # Speed-up 2: GUID_TIMEOUT is 1.5 s of wall time, so a loaded machine that stalls this
        # thread between the last setpoint and the first sample does not eat the hold window
        # (at 4x it was 0.75 s, and CI once sampled the braking already).
        async with running_host(3, speedup=2.0, personality_name="ardupilot") as host:
            out = await asyncio.to_thread(_flight, host.ports[2])
            return out, host.vehicle(2)

    out, vehicle = _run(scenario)
    v0 = out["v0"]
    assert v0 > 1.0
    # Until GUID_TIMEOUT (3 s of vehicle time) after the last setpoint it keeps its velocity ...
    holding = [(round(t, 2), round(vy, 3)) for t, vy in out["samples"] if t < 2.8]
    assert all(abs(vy - v0) < 0.05 for _, vy in holding), f"v0 {v0:.3f}, samples {holding}"
    # ... then brakes to a stop, staying in GUIDED.
    assert any(abs(vy - v0) > 0.2 for t, vy in out["samples"] if 3.0 < t < 4.0)
    assert all(abs(vy) < 0.3 for t, vy in out["samples"] if t > 8.5)
    assert out["mode_after"] == 4
    params = out["params"]
    assert params["GUID_TIMEOUT"][0] == pytest.approx(3.0)
    assert params["MAV_SYSID"][0] == 3  # ArduPilot 4.7's name (SYSID_THISMAV before)
    assert {c for _, c in params.values()} == {7}
    assert out["param_set"] == pytest.approx(2.5) and out["param_read"] == pytest.approx(2.5)
    assert vehicle.params["offboard_timeout_s"] == pytest.approx(2.5)
    assert out["mission_count"] == 0
    assert out["unknown_cmd"] == mavutil.mavlink.MAV_RESULT_UNSUPPORTED
    assert out["version"].capabilities & mavutil.mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    assert out["home"].latitude != 0
    assert out["timesync"].tc1 > 0
    assert out["system_time"].time_boot_ms > 0
    assert vehicle.counters.dropped == 0


def _run(factory):
    result = {}

    async def main():
        result["v"] = await factory()

    run(main())
    return result["v"]
