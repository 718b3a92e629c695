"""Telemetry messages: builders that turn a vehicle's state into what PX4/ArduPilot stream.

Rates are in sim time (a 10 Hz stream at --speedup 20 sends 200 messages per wall second),
so a client that timestamps by time_boot_ms sees a normal vehicle; `schedule.Scheduler`
decides when each message of each vehicle is due.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING

from plmarl_sitl.deploy.mavlink.codec import Fields, Message, dialect
from plmarl_sitl.deploy.mavlink.wire import MASK_POS, MASK_VEL

if TYPE_CHECKING:
    from plmarl_sitl.sitl.autopilot.vehicle import Vehicle

d = dialect
G = 9.80665
# What a builder gives: a message, or (the streams sent every substep) its id and fields,
# packed to the same frame without a message object (`Codec.encode`).
Outgoing = Message | Fields

# Sensors a healthy multirotor reports; MAVSDK derives health from these bits
# (GPS present+healthy -> local/global position OK; PREARM_CHECK -> armable).
SENSORS = (
    d.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | d.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | d.MAV_SYS_STATUS_SENSOR_3D_MAG
    | d.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | d.MAV_SYS_STATUS_SENSOR_GPS
    | d.MAV_SYS_STATUS_AHRS
    | d.MAV_SYS_STATUS_PREARM_CHECK
)

# Default stream rates (Hz of sim time), close to PX4's onboard/UDP profile.
DEFAULT_RATES: dict[int, float] = {
    d.MAVLINK_MSG_ID_HEARTBEAT: 1.0,
    d.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
    d.MAVLINK_MSG_ID_SYSTEM_TIME: 1.0,
    d.MAVLINK_MSG_ID_GPS_RAW_INT: 1.0,
    d.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 1.0,
    d.MAVLINK_MSG_ID_HOME_POSITION: 0.5,
    d.MAVLINK_MSG_ID_ATTITUDE: 10.0,
    d.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 10.0,
    d.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 10.0,
    d.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED: 10.0,
    d.MAVLINK_MSG_ID_VFR_HUD: 0.0,
    d.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN: 0.0,
}


def _ms(v: Vehicle) -> int:
    # Rounded, not truncated: the clock is a sum of float substeps, and a whole second
    # summed to 11.999999999 s must still read 12000 ms.
    return int(v.fleet.now * 1000 + 0.5) & 0xFFFFFFFF


def heartbeat(v: Vehicle) -> Message:
    flags = v.mode_spec.base_flags
    base = v.personality.base_mode_flags if flags is None else flags
    if v.armed:
        base |= d.MAV_MODE_FLAG_SAFETY_ARMED
    if not v.fleet.boot.ready(v.fleet.now):
        status = d.MAV_STATE_BOOT
    elif v.failsafe:
        status = d.MAV_STATE_CRITICAL  # PX4, measured: while a failsafe holds the mode
    else:
        status = d.MAV_STATE_ACTIVE if v.armed else d.MAV_STATE_STANDBY
    return v.codec.mav.heartbeat_encode(
        d.MAV_TYPE_QUADROTOR, v.personality.autopilot, base, v.custom_mode, status, 3
    )


def sys_status(v: Vehicle) -> Message:
    return v.codec.mav.sys_status_encode(SENSORS, SENSORS, SENSORS, 250, 16200, -1, 100, 0, 0, 0, 0, 0, 0)


def system_time(v: Vehicle) -> Message:
    return v.codec.mav.system_time_encode(int(v.fleet.unix_time_s() * 1e6), _ms(v))


def gps_raw_int(v: Vehicle) -> Message:
    lat, lon, alt = v.geodetic()
    vn, ve, _ = v.velocity()
    dark = v.gps_lost_at is not None  # a GPS loss: no fix, no satellites (PX4 SIH, measured)
    return v.codec.mav.gps_raw_int_encode(
        int(v.fleet.unix_time_s() * 1e6), d.GPS_FIX_TYPE_NO_GPS if dark else d.GPS_FIX_TYPE_3D_FIX, int(lat * 1e7),
        int(lon * 1e7), int(alt * 1000), 80, 120, int(math.hypot(vn, ve) * 100), 65535, 0 if dark else 12,
    )


def extended_sys_state(v: Vehicle) -> Message:
    return v.codec.mav.extended_sys_state_encode(d.MAV_VTOL_STATE_UNDEFINED, v.landed_state)


def home_position(v: Vehicle) -> Message | None:
    if not v.fleet.boot.origin(v.fleet.now):
        return None  # no home before the EKF has an origin
    lat, lon, alt = v.home_geodetic
    return v.codec.mav.home_position_encode(
        int(lat * 1e7), int(lon * 1e7), int(alt * 1000), 0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0,
        int(v.fleet.unix_time_s() * 1e6),
    )


def gps_global_origin(v: Vehicle) -> Message | None:
    if not v.fleet.boot.origin(v.fleet.now):
        return None
    lat, lon, alt = v.home_geodetic
    return v.codec.mav.gps_global_origin_encode(int(lat * 1e7), int(lon * 1e7), int(alt * 1000))


def attitude(v: Vehicle) -> Outgoing:
    an, ae, _ = v.last_accel()
    yaw = v.yaw
    fwd = math.cos(yaw) * an + math.sin(yaw) * ae
    right = -math.sin(yaw) * an + math.cos(yaw) * ae
    return Fields((d.MAVLINK_MSG_ID_ATTITUDE, (_ms(v), math.atan2(right, G), -math.atan2(fwd, G), yaw, 0.0, 0.0, 0.0)))


def local_position_ned(v: Vehicle) -> Outgoing | None:
    if not v.fleet.boot.position(v.fleet.now) or v.aiding_stopped:
        return None  # the EKF does not use GPS yet, or no more (ArduCopter keeps GLOBAL_POSITION_INT)
    x, y, z = v.nav_position()
    vx, vy, vz = v.velocity()
    ms = _ms(v)
    v.fleet.telemetry_ms[v.index] = ms  # a lockstep agent owes a setpoint stamped with it
    return Fields((d.MAVLINK_MSG_ID_LOCAL_POSITION_NED, (ms, x, y, z, vx, vy, vz)))


def global_position_int(v: Vehicle) -> Outgoing | None:
    if not v.fleet.boot.position(v.fleet.now):
        return None
    lat, lon, alt = v.geodetic()
    _, _, z = v.nav_position()
    vx, vy, vz = v.velocity()
    hdg = int(math.degrees(v.yaw) % 360 * 100)
    return Fields((d.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, (
        _ms(v), int(lat * 1e7), int(lon * 1e7), int(alt * 1000), int(-z * 1000),
        int(vx * 100), int(vy * 100), int(vz * 100), hdg,
    )))


def position_target_local_ned(v: Vehicle) -> Outgoing | None:
    target = v.active_target()
    if target is None:
        return None
    mask, (a, b, c) = target
    vec = [0.0] * 9
    group = 0 if mask & MASK_POS == 0 else 1 if mask & MASK_VEL == 0 else 2
    vec[3 * group : 3 * group + 3] = (a, b, c)
    return Fields((d.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED, (_ms(v), d.MAV_FRAME_LOCAL_NED, mask, *vec, v.yaw, 0.0)))


def vfr_hud(v: Vehicle) -> Message:
    vx, vy, vz = v.velocity()
    _, _, alt = v.geodetic()
    speed = math.hypot(vx, vy)
    hdg = int(math.degrees(v.yaw) % 360)
    return v.codec.mav.vfr_hud_encode(speed, speed, hdg, 50 if v.armed else 0, alt, -vz)


def autopilot_version(v: Vehicle) -> Message:
    caps = (
        d.MAV_PROTOCOL_CAPABILITY_MAVLINK2
        | d.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
        | d.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
        | d.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    )
    if v.personality.param_bytewise:
        caps |= d.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
    else:
        caps |= d.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST
    sw = (1 << 24) | (15 << 16) | (0 << 8) | 255  # 1.15.0 release
    uid2 = list(v.sysid.to_bytes(2, "little")) + [0] * 16
    return v.codec.mav.autopilot_version_encode(
        caps, sw, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0x26AC, 0x0011, v.sysid, uid2
    )


BUILDERS: dict[int, Callable[[Vehicle], Outgoing | None]] = {
    d.MAVLINK_MSG_ID_HEARTBEAT: heartbeat,
    d.MAVLINK_MSG_ID_SYS_STATUS: sys_status,
    d.MAVLINK_MSG_ID_SYSTEM_TIME: system_time,
    d.MAVLINK_MSG_ID_GPS_RAW_INT: gps_raw_int,
    d.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: extended_sys_state,
    d.MAVLINK_MSG_ID_HOME_POSITION: home_position,
    d.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN: gps_global_origin,
    d.MAVLINK_MSG_ID_ATTITUDE: attitude,
    d.MAVLINK_MSG_ID_LOCAL_POSITION_NED: local_position_ned,
    d.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: global_position_int,
    d.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED: position_target_local_ned,
    d.MAVLINK_MSG_ID_VFR_HUD: vfr_hud,
    d.MAVLINK_MSG_ID_AUTOPILOT_VERSION: autopilot_version,
}


def message_id(name_or_id: str | int) -> int:
    """Message id from a name ('LOCAL_POSITION_NED') or id; KeyError if unknown."""
    if isinstance(name_or_id, int):
        return name_or_id
    return getattr(d, f"MAVLINK_MSG_ID_{name_or_id.upper()}")
