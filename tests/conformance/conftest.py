"""Fixtures of the differential suite: one started target per module and parameter.

`target` is "emulator" (always) or "arducopter" (only with ARDUCOPTER=/path/to/arducopter;
skipped with the reason otherwise). Starting it records the start-up (`record_boot`): the
vehicle-clock instant of each STATUSTEXT, of the first HOME_POSITION and of the first
LOCAL_POSITION_NED, and the answer to an arm in GUIDED between home and position.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from pymavlink import mavutil

from conformance.link import Link
from conformance.targets import Target, connect, start_arducopter, start_emulator

TARGETS = ["emulator", "arducopter"]
BOOT_SIM_S = 60.0  # vehicle seconds the start-up may take (the real one: ~40)


def _start(name: str, workdir: Path) -> Target:
    if name == "emulator":
        return start_emulator(workdir)
    binary = os.environ.get("ARDUCOPTER")
    if not binary:
        pytest.skip("real ArduCopter not given: set ARDUCOPTER=/path/to/arducopter (see docs/CONFORMANCE.md)")
    if not os.access(binary, os.X_OK):
        pytest.fail(f"ARDUCOPTER={binary} is not an executable file")
    return start_arducopter(binary, workdir)


def record_boot(link: Link, target: Target) -> dict:
    """Follow the start-up until LOCAL_POSITION_NED streams; times are vehicle seconds."""
    mav = link.mav
    boot: dict = {"texts": [], "heartbeat": None, "home_s": None, "lpn_s": None, "arm_before_position": None}

    def ask_interval(msgid: int) -> int | None:
        for _ in range(20):  # commands sent in the first instants may go unanswered: ask again
            result = link.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, msgid, 100_000, 0, 0, 0, 0, 0, sim_s=0.5)
            if result is not None:
                return result
        return None

    # An interval asked for at once is acknowledged, but does it survive the start-up? (VFR_HUD:
    # streamed by default by neither target.)
    boot["early_interval"] = ask_interval(mav.MAVLINK_MSG_ID_VFR_HUD)
    link.wait("STATUSTEXT", lambda t: t.text == "ArduPilot Ready", sim_s=BOOT_SIM_S)
    boot["early_interval_kept"] = link.wait("VFR_HUD", sim_s=2.0, wall_s=0.5 + 4.0 / target.speedup) is not None
    # The vehicle clock: SYSTEM_TIME at 10 Hz. LOCAL_POSITION_NED asked for now, sent once it exists.
    for msgid in (mav.MAVLINK_MSG_ID_SYSTEM_TIME, mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED):
        result = ask_interval(msgid)
        assert result == mav.MAV_RESULT_ACCEPTED, f"SET_MESSAGE_INTERVAL {msgid}: {result}"
    deadline = time.monotonic() + target.wall(BOOT_SIM_S)
    while time.monotonic() < deadline and boot["lpn_s"] is None:
        msg = link.recv(0.2)
        if msg is None:
            continue
        kind = msg.get_type()
        if kind == "HEARTBEAT" and msg.get_srcComponent() == 1 and boot["heartbeat"] is None:
            boot["heartbeat"] = msg
        elif kind == "HOME_POSITION" and boot["home_s"] is None:
            boot["home_s"] = link.clock_s
        elif kind == "LOCAL_POSITION_NED":
            boot["lpn_s"] = msg.time_boot_ms / 1000
        if boot["home_s"] is not None and boot["arm_before_position"] is None and boot["lpn_s"] is None:
            link.command(mav.MAV_CMD_DO_SET_MODE, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4, 0, 0, 0, 0, 0)
            boot["arm_before_position"] = link.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1, 0, 0, 0, 0, 0, 0)
    boot["texts"] = list(link.texts)
    return boot


@pytest.fixture(scope="module", params=TARGETS)
def target(request: pytest.FixtureRequest) -> Iterator[Target]:
    workdir = Path(tempfile.mkdtemp(prefix=f"plmarl-conformance-{request.param}-"))
    try:
        t = _start(request.param, workdir)
    except BaseException:  # a skip, too: leave no directory behind
        shutil.rmtree(workdir, ignore_errors=True)
        raise
    t0 = time.monotonic()
    try:
        link = Link(connect(t), t)
        t.boot = record_boot(link, t)
        t.boot["wall_s"] = time.monotonic() - t0
        t.link = link  # type: ignore[attr-defined]
        yield t
        link.close()
    finally:
        t.stop()
        if os.environ.get("CONFORMANCE_KEEP"):  # logs, eeprom.bin, ArduPilot's logs/
            print(f"{t.name}: working directory kept at {workdir}")
        else:
            shutil.rmtree(workdir, ignore_errors=True)


@pytest.fixture
def link(target: Target) -> Link:
    return target.link  # type: ignore[attr-defined]


# ---------------------------------------------------------------------------- PX4
PX4_TARGETS = ["emulator", "px4"]
PX4_BOOT_S = 10.0  # vehicle seconds the PX4 start-up may take (the real one: ~4.5 to "Ready for takeoff!")


def record_px4_boot(link: Link, target: Target) -> dict:
    """Follow a PX4 start-up until "Ready for takeoff!": vehicle seconds (time_boot_ms of the
    streamed LOCAL_POSITION_NED, ATTITUDE ...) of the first HEARTBEAT, HOME_POSITION and
    LOCAL_POSITION_NED, and the heartbeats' system_status before and after."""
    boot: dict = {"heartbeat": None, "heartbeat_s": None, "home": None, "home_s": None, "lpn_s": None,
                  "ready_s": None, "status_before_ready": set(), "status_after_ready": set()}
    deadline = time.monotonic() + target.wall(PX4_BOOT_S)
    while time.monotonic() < deadline:
        msg = link.recv(0.2)
        if msg is None:
            continue
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            if boot["heartbeat"] is None:
                boot["heartbeat"], boot["heartbeat_s"] = msg, link.clock_s
            if msg.system_status == mavutil.mavlink.MAV_STATE_STANDBY and boot["ready_s"] is None:
                boot["ready_s"] = link.clock_s  # "Ready for takeoff!" (PX4 sends no STATUSTEXT for it)
            boot["status_before_ready" if boot["ready_s"] is None else "status_after_ready"].add(msg.system_status)
            if boot["ready_s"] is not None and link.clock_s > boot["ready_s"] + 1.5:
                break
        elif kind == "HOME_POSITION" and boot["home"] is None:
            boot["home"], boot["home_s"] = msg, link.clock_s
        elif kind == "LOCAL_POSITION_NED" and boot["lpn_s"] is None:
            boot["lpn_s"] = msg.time_boot_ms / 1000
    boot["texts"] = list(link.texts)
    return boot


@pytest.fixture(scope="module", params=PX4_TARGETS)
def px4_target(request: pytest.FixtureRequest) -> Iterator[Target]:
    from conformance.px4_sitl import px4_build_or_skip
    from conformance.targets import start_real_px4

    build = px4_build_or_skip() if request.param == "px4" else None
    workdir = Path(tempfile.mkdtemp(prefix=f"plmarl-conformance-px4-{request.param}-"))
    t: Target | None = None
    try:
        if build is None:
            t = start_emulator(workdir, speedup=5.0, personality="px4")
            link = Link(connect(t), t)
        else:
            # Listen before PX4 starts: it sends to 14540 + i from its first instant.
            from conformance.px4_sitl import PX4_INSTANCE

            m = mavutil.mavlink_connection(f"udpin:127.0.0.1:{14540 + PX4_INSTANCE}", source_system=255,
                                           source_component=190)
            t = start_real_px4(build, workdir)
            link = Link(m, t)
        t0 = time.monotonic()
        t.boot = record_px4_boot(link, t)
        t.boot["wall_s"] = time.monotonic() - t0
        t.link = link  # type: ignore[attr-defined]
        yield t
        link.close()
        b = t.boot  # what docs/CONFORMANCE.md records (pytest -s shows it)
        keys = ("lpn_s", "home_s", "heartbeat_s", "ready_s", "lift_s", "climb_rate", "loiter_after_s", "peak_alt_m", "accel_vx", "failsafe_after_s",
                "rtl_from_alt_m", "rtl_disarmed_after_s", "landed_z_m", "gps_loss_modes", "no_gps_failsafe_after_s",
                "gps_back_rtl_after_s", "motor_text_after_s", "fall_m_in_4s", "wall_s")
        print(f"\nPX4 conformance, {request.param}: " + ", ".join(f"{k} {b.get(k)!r}" for k in keys))
    finally:
        if t is not None:
            t.stop()
        if os.environ.get("CONFORMANCE_KEEP"):
            print(f"px4 {request.param}: working directory kept at {workdir}")
        else:
            shutil.rmtree(workdir, ignore_errors=True)


@pytest.fixture
def px4_link(px4_target: Target) -> Link:
    return px4_target.link  # type: ignore[attr-defined]
