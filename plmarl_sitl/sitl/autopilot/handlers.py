"""Incoming MAVLink: validate, dispatch, answer. Bad input is counted, never raised.

Each handler gets the vehicle, the decoded message and the sender's address. Replies
(COMMAND_ACK, PARAM_VALUE, ...) go to the sender; streams go to every peer. Commands
follow PX4/ArduPilot semantics that MAVSDK and pymavlink rely on: every COMMAND_LONG gets
exactly one COMMAND_ACK matched on the command id, unknown commands get UNSUPPORTED, and
unset parameters arrive as NaN and are tolerated where the command allows it.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from operator import attrgetter

from plmarl_sitl.deploy.mavlink.codec import Message, dialect, param_id_str
from plmarl_sitl.deploy.mavlink.wire import FORCE_ARM_MAGIC, MASK_ACC, MASK_FORCE_SET, MASK_POS, MASK_VEL
from plmarl_sitl.sitl.autopilot import telemetry
from plmarl_sitl.sitl.autopilot.guidance import Kind
from plmarl_sitl.sitl.autopilot.vehicle import ACCEPTED, DENIED, Vehicle

d = dialect
UNSUPPORTED = d.MAV_RESULT_UNSUPPORTED
Addr = tuple[str, int]

SIGNATURE_FAULTS = ("unsigned", "bad_signature")

# Sanity bounds on setpoint fields: beyond these a value is garbage, not a wish to clip.
# PX4 SIH's sensor_gps_sim: SIM_GPS_USED satellites; below 4 (GPS_FIX_MIN_SATELLITES here) no fix.
GPS_SATELLITES_PARAM = "SIM_GPS_USED"
GPS_FIX_MIN_SATELLITES = 4
FAILURE_UNIT_SYSTEM_MOTOR, FAILURE_TYPE_OFF = d.FAILURE_UNIT_SYSTEM_MOTOR, d.FAILURE_TYPE_OFF
MAX_ABS = {Kind.POSITION: 1e6, Kind.VELOCITY: 1e3, Kind.ACCEL: 1e3}


def on_datagram(v: Vehicle, data: bytes, addr: Addr) -> None:
    """Entry point from the UDP protocol."""
    if v.killed:
        return
    v.counters.datagrams += 1
    decoded = v.codec.decode_datagram(data)
    if decoded.fault is not None:
        v.drop(decoded.fault, f"{len(data)} bytes from {addr[0]}:{addr[1]}")
        if decoded.fault in SIGNATURE_FAULTS:
            # Well-formed MAVLink without the key: the sender still gets the telemetry (signed,
            # readable without the key), as the UDP port of a real autopilot answers whoever
            # speaks; it sees the vehicle and the STATUSTEXT that its input was dropped.
            v.remember_peer(addr)
    for msg in decoded.messages:
        v.counters.messages += 1
        v.remember_peer(addr)
        handler = HANDLERS.get(msg.get_msgId())
        if handler is not None:
            handler(v, msg, addr)


def _for_me(v: Vehicle, msg: Message) -> bool:
    ts = getattr(msg, "target_system", 0)
    tc = getattr(msg, "target_component", 0)
    return ts in (0, v.sysid) and tc in (0, d.MAV_COMP_ID_AUTOPILOT1)


def _ack(v: Vehicle, msg: Message, addr: Addr, command: int, result: int) -> None:
    v.send(
        v.codec.mav.command_ack_encode(command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()),
        addr,
    )


# ---------------------------------------------------------------------------- setpoints


def _setpoint(v: Vehicle, msg: Message, addr: Addr) -> None:
    if not _for_me(v, msg):
        return
    mask = msg.type_mask
    if msg.coordinate_frame != d.MAV_FRAME_LOCAL_NED:
        v.drop("bad_value", f"setpoint frame {msg.coordinate_frame} (only LOCAL_NED)")
        return
    if mask & MASK_FORCE_SET:
        v.drop("bad_value", "setpoint with FORCE_SET")
        return
    # The first group the mask does not ignore is the setpoint (position, velocity,
    # acceleration, in that order). Its fields are read only for that group: an agent's
    # acceleration setpoint, 20 x 10 per vehicle-second in SITL, reads three, not nine.
    for bits, kind in _GROUPS:
        used = mask & bits
        if used == bits:
            continue  # group ignored
        if used != 0:
            v.drop("bad_value", f"partial type_mask 0x{mask:04x}")
            return
        a, b, c = _GROUP_FIELDS[kind](msg)
        lim = MAX_ABS[kind]
        if not (math.isfinite(a) and math.isfinite(b) and math.isfinite(c) and abs(a) <= lim and abs(b) <= lim
                and abs(c) <= lim):
            v.drop("bad_value", f"{kind.name.lower()} setpoint {(a, b, c)}")
            return
        v.accept_setpoint(kind, (float(a), float(b), float(c)), mask)
        if msg.time_boot_ms > 0:  # a lockstep agent stamps the telemetry it answers (sitl.lockstep)
            v.fleet.answered(v.index, msg.time_boot_ms)
        return
    v.drop("bad_value", f"type_mask 0x{mask:04x} ignores everything")


_GROUPS = ((MASK_POS, Kind.POSITION), (MASK_VEL, Kind.VELOCITY), (MASK_ACC, Kind.ACCEL))
_GROUP_FIELDS = {
    Kind.POSITION: attrgetter("x", "y", "z"),
    Kind.VELOCITY: attrgetter("vx", "vy", "vz"),
    Kind.ACCEL: attrgetter("afx", "afy", "afz"),
}


# ---------------------------------------------------------------------------- commands

CommandFn = Callable[[Vehicle, list[float], Message, Addr], int]


def _finite(*xs: float) -> bool:
    return all(math.isfinite(x) for x in xs)


def _cmd_arm(v: Vehicle, p: list[float], msg: Message, addr: Addr) -> int:
    if not _finite(p[0]) or p[0] not in (0.0, 1.0):
        v.drop("bad_value", f"arm param1 {p[0]}")
        return v.personality.answers.bad_arm_param
    force = p[1] == FORCE_ARM_MAGIC
    return v.arm(force) if p[0] == 1.0 else v.disarm(force)


def _cmd_set_mode(v: Vehicle, p: list[float], msg: Message, addr: Addr) -> int:
    if not _finite(p[0], p[1]):
        v.drop("bad_value", f"DO_SET_MODE params {p[:3]}")
        return DENIED
    if not int(p[0]) & d.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
        return DENIED
    spec = v.personality.mode_by_custom(v.personality.custom_mode_from_set_mode(p[1], p[2]))
    if spec is None:
        return _no_such_mode(v, int(p[1]))
    return v.set_mode(spec)


def _no_such_mode(v: Vehicle, number: int) -> int:
    result = v.personality.answers.refused
    if result != DENIED:  # ArduPilot says why it failed
        v.statustext(f"No such mode {number}", d.MAV_SEVERITY_WARNING)
    return result


def _cmd_takeoff(v: Vehicle, p: list[float], msg: Message, addr: Addr) -> int:
    alt = p[6]
    if math.isnan(alt):
        rel = None
    elif not math.isfinite(alt):
        v.drop("bad_value", f"takeoff altitude {alt}")
        return DENIED
    elif v.personality.takeoff_alt_is_amsl:
        rel = alt - v.home_geodetic[2]
    else:
        rel = alt  # ArduPilot: above home; 0 or below is "taking off downwards" and fails
    return v.takeoff(rel)


def _cmd_land(v: Vehicle, p: list[float], msg: Message, addr: Addr) -> int:
    return v.land()


def _cmd_set_message_interval(v: Vehicle, p: list[float], msg: Message, addr: Addr) -> int:
    answers = v.personality.answers
    if answers.interval_param3_must_be_zero and p[2] != 0.0:
        # Reserved in the MAVLink spec ("send 0"); ArduPilot denies anything else, NaN included.
        v.drop("bad_value", f"SET_MESSAGE_INTERVAL param3 {p[2]} (reserved: 0)")
        return DENIED
    if not _finite(p[0], p[1]):
        v.drop("bad_value", f"SET_MESSAGE_INTERVAL params {p[:2]}")
        return DENIED
    msgid, interval_us = int(p[0]), p[1]
    if msgid not in telemetry.BUILDERS or msgid == d.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
        return answers.unknown_stream
    if interval_us < 0 and interval_us != -1 and answers.only_minus_one_stops:
        return DENIED
    if not v.fleet.boot.ready(v.fleet.now):
        # ArduPilot acks it but sets up its streams from SRn_ parameters on its first send
        # after start-up, which overwrites any interval set before "ArduPilot Ready" (measured).
        return ACCEPTED
    if interval_us < 0:
        hz = 0.0
    elif interval_us == 0:
        hz = v.fleet.default_rates.get(msgid, 0.0)
    elif interval_us < 1000:  # > 1 kHz of sim time is not a telemetry rate
        return DENIED
    else:
        hz = 1e6 / interval_us
    v.fleet.streams.set_rate(v.index, msgid, hz, v.fleet.now)
    return ACCEPTED


def _cmd_get_message_interval(v: Vehicle, p: list[float], msg: Message, addr: Addr) -> int:
    if not _finite(p[0]):
        return DENIED
    msgid = int(p[0])
    hz = v.fleet.streams.rate(v.index, msgid)
    interval = int(1e6 / hz) if hz > 0 else (-1 if msgid in telemetry.BUILDERS else 0)
    v.send(v.codec.mav.message_interval_encode(msgid, interval), addr)
    return ACCEPTED


def _send_once(v: Vehicle, msgid: int, addr: Addr) -> int:
    builder = telemetry.BUILDERS.get(msgid)
    if builder is None:
        return v.personality.answers.unknown_request
    m = builder(v)
    if m is None:  # e.g. home before the EKF origin
        return v.personality.answers.unavailable_request
    v.send(m, addr)
    return ACCEPTED


def _cmd_request_message(v: Vehicle, p: list[float], msg: Message, addr: Addr) -> int:
    if not _finite(p[0]):
        v.drop("bad_value", f"REQUEST_MESSAGE id {p[0]}")
        return DENIED
    return _send_once(v, int(p[0]), addr)


def _cmd_autopilot_capabilities(v: Vehicle, p: list[float], msg: Message, addr: Addr) -> int:
    return _send_once(v, d.MAVLINK_MSG_ID_AUTOPILOT_VERSION, addr)


def _cmd_get_home(v: Vehicle, p: list[float], msg: Message, addr: Addr) -> int:
    if telemetry.home_position(v) is None:
        return v.personality.answers.refused  # ArduPilot: FAILED until home is set
    return _send_once(v, d.MAVLINK_MSG_ID_HOME_POSITION, addr)


def _cmd_inject_failure(v: Vehicle, p: list[float], msg: Message, addr: Addr) -> int:
    """PX4's MAV_CMD_INJECT_FAILURE: motor off is what the missions use; the rest is left out."""
    if not v.personality.inject_failure:
        return UNSUPPORTED
    if (p[0], p[1]) != (FAILURE_UNIT_SYSTEM_MOTOR, FAILURE_TYPE_OFF):
        return UNSUPPORTED
    v.fail_motor()
    return ACCEPTED


COMMANDS: dict[int, CommandFn] = {
    d.MAV_CMD_COMPONENT_ARM_DISARM: _cmd_arm,
    d.MAV_CMD_DO_SET_MODE: _cmd_set_mode,
    d.MAV_CMD_NAV_TAKEOFF: _cmd_takeoff,
    d.MAV_CMD_NAV_LAND: _cmd_land,
    d.MAV_CMD_INJECT_FAILURE: _cmd_inject_failure,
    d.MAV_CMD_SET_MESSAGE_INTERVAL: _cmd_set_message_interval,
    d.MAV_CMD_GET_MESSAGE_INTERVAL: _cmd_get_message_interval,
    d.MAV_CMD_REQUEST_MESSAGE: _cmd_request_message,
    d.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: _cmd_autopilot_capabilities,
    d.MAV_CMD_GET_HOME_POSITION: _cmd_get_home,
}


def _command(v: Vehicle, msg: Message, addr: Addr, params: list[float]) -> None:
    if not _for_me(v, msg):
        return
    fn = COMMANDS.get(msg.command)
    result = UNSUPPORTED if fn is None else fn(v, params, msg, addr)
    _ack(v, msg, addr, msg.command, result)


def _command_long(v: Vehicle, msg: Message, addr: Addr) -> None:
    p = [msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7]
    _command(v, msg, addr, p)


def _command_int(v: Vehicle, msg: Message, addr: Addr) -> None:
    p = [msg.param1, msg.param2, msg.param3, msg.param4, msg.x * 1e-7, msg.y * 1e-7, msg.z]
    _command(v, msg, addr, p)


def _set_mode_msg(v: Vehicle, msg: Message, addr: Addr) -> None:
    """Legacy SET_MODE (MAVProxy, old GCSs). ArduPilot 4.7 changes the mode without a
    COMMAND_ACK (the client sees it in the next HEARTBEAT); our PX4 personality acks it."""
    if msg.target_system not in (0, v.sysid):
        return
    spec = v.personality.mode_by_custom(msg.custom_mode)
    result = _no_such_mode(v, msg.custom_mode) if spec is None else v.set_mode(spec)
    if v.personality.answers.set_mode_message_acked:
        _ack(v, msg, addr, d.MAVLINK_MSG_ID_SET_MODE, result)


# ---------------------------------------------------------------------------- params


def _param_value(v: Vehicle, index: int, addr: Addr | None) -> None:
    name, value, ptype = v.params.wire(index)
    v.send(v.codec.mav.param_value_encode(name.encode(), value, ptype, len(v.params.specs), index), addr)


def _param_request_list(v: Vehicle, msg: Message, addr: Addr) -> None:
    if _for_me(v, msg):
        for i in range(len(v.params.specs)):
            _param_value(v, i, addr)


def _param_request_read(v: Vehicle, msg: Message, addr: Addr) -> None:
    if not _for_me(v, msg):
        return
    if msg.param_index >= 0:
        index = msg.param_index if msg.param_index < len(v.params.specs) else None
    else:
        index = v.params.index_of(param_id_str(msg.param_id))
    if index is not None:
        _param_value(v, index, addr)


def _param_set(v: Vehicle, msg: Message, addr: Addr) -> None:
    if not _for_me(v, msg):
        return
    name = param_id_str(msg.param_id)
    index = v.params.index_of(name)
    if index is None:
        return  # PX4 and ArduPilot stay silent on unknown names
    refused = v.params.set_from_wire(name, msg.param_value)
    if refused is not None:
        v.drop("bad_value", f"PARAM_SET {name}={msg.param_value}: {refused}")
    else:
        v.params_changed()
        if name == GPS_SATELLITES_PARAM:  # PX4 SIH's GPS: the fault injection a real one is given
            v.gps_param_set(v.params["gps_satellites"] >= GPS_FIX_MIN_SATELLITES)
    _param_value(v, index, None)  # broadcast the (new or unchanged) value, as PX4 does


# ---------------------------------------------------------------------------- misc


def _mission_request_list(v: Vehicle, msg: Message, addr: Addr) -> None:
    if _for_me(v, msg):
        v.send(v.codec.mav.mission_count_encode(msg.get_srcSystem(), msg.get_srcComponent(), 0, msg.mission_type), addr)


def _mission_clear_all(v: Vehicle, msg: Message, addr: Addr) -> None:
    if _for_me(v, msg):
        v.send(
            v.codec.mav.mission_ack_encode(msg.get_srcSystem(), msg.get_srcComponent(), d.MAV_MISSION_ACCEPTED, msg.mission_type),
            addr,
        )


def _mission_count(v: Vehicle, msg: Message, addr: Addr) -> None:
    """Mission upload: this emulator flies setpoints only, so it refuses politely."""
    if _for_me(v, msg):
        v.send(
            v.codec.mav.mission_ack_encode(msg.get_srcSystem(), msg.get_srcComponent(), d.MAV_MISSION_UNSUPPORTED, msg.mission_type),
            addr,
        )


def _timesync(v: Vehicle, msg: Message, addr: Addr) -> None:
    if msg.tc1 == 0:  # a request: answer with our clock (sim time, ns)
        v.send(v.codec.mav.timesync_encode(int(v.fleet.now * 1e9), msg.ts1), addr)


_FTP_NAK, _FTP_OPEN_RO = 129, 4
_FTP_ERR_FAIL, _FTP_ERR_NOT_FOUND = 1, 10


def _ftp(v: Vehicle, msg: Message, addr: Addr) -> None:
    """MAVFTP: there are no files. A prompt NAK lets MAVProxy fall back to PARAM_REQUEST_LIST
    at once instead of after its FTP timeout."""
    if msg.target_system not in (0, v.sysid) or len(msg.payload) < 12:
        return
    pl = bytes(msg.payload)
    seq, session, opcode = pl[0] | pl[1] << 8, pl[2], pl[3]
    err = _FTP_ERR_NOT_FOUND if opcode == _FTP_OPEN_RO else _FTP_ERR_FAIL
    reply = bytes([(seq + 1) & 0xFF, (seq + 1) >> 8 & 0xFF, session, _FTP_NAK, 1, opcode, 0, 0, 0, 0, 0, 0, err])
    v.send(
        v.codec.mav.file_transfer_protocol_encode(0, msg.get_srcSystem(), msg.get_srcComponent(), list(reply.ljust(251, b"\0"))),
        addr,
    )


def _setup_signing(v: Vehicle, msg: Message, addr: Addr) -> None:
    """SETUP_SIGNING (no answer, as on the real ones). It takes effect at once on the
    vehicle's link; a signed vehicle takes it only signed with the current key."""
    if not _for_me(v, msg):
        return
    if v.armed and v.personality.setup_signing_disarmed_only:
        v.statustext("ERROR: Won't setup signing when armed", d.MAV_SEVERITY_WARNING)
        return
    v.setup_signing(bytes(msg.secret_key), msg.initial_timestamp)


Handler = Callable[[Vehicle, Message, Addr], None]

HANDLERS: dict[int, Handler] = {
    d.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED: _setpoint,
    d.MAVLINK_MSG_ID_COMMAND_LONG: _command_long,
    d.MAVLINK_MSG_ID_COMMAND_INT: _command_int,
    d.MAVLINK_MSG_ID_SET_MODE: _set_mode_msg,
    d.MAVLINK_MSG_ID_PARAM_REQUEST_LIST: _param_request_list,
    d.MAVLINK_MSG_ID_PARAM_REQUEST_READ: _param_request_read,
    d.MAVLINK_MSG_ID_PARAM_SET: _param_set,
    d.MAVLINK_MSG_ID_MISSION_REQUEST_LIST: _mission_request_list,
    d.MAVLINK_MSG_ID_MISSION_CLEAR_ALL: _mission_clear_all,
    d.MAVLINK_MSG_ID_MISSION_COUNT: _mission_count,
    d.MAVLINK_MSG_ID_TIMESYNC: _timesync,
    d.MAVLINK_MSG_ID_FILE_TRANSFER_PROTOCOL: _ftp,
    d.MAVLINK_MSG_ID_SETUP_SIGNING: _setup_signing,
}
