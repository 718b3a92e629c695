"""Autopilot personalities: how PX4 and ArduPilot spell modes and parameters on the wire.

The emulator has one set of behaviours (hold, offboard, takeoff, land, brake); a
personality maps them to the custom_mode numbers, parameter names, units and encodings
that real clients expect, so MAVSDK, pymavlink and MAVProxy all recognise the vehicle.
Facts come from PX4 `px4_custom_mode.h`, ArduCopter `mode.h` and `Parameters.cpp`.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from plmarl_sitl.deploy.mavlink.codec import dialect, enum_name
from plmarl_sitl.errors import UserError


class Behaviour(enum.Enum):
    """What the vehicle does in a mode. Modes without RC sticks hold position."""

    HOLD = "hold"
    OFFBOARD = "offboard"  # PX4 OFFBOARD, ArduPilot GUIDED: follow external setpoints
    TAKEOFF = "takeoff"
    LAND = "land"
    BRAKE = "brake"
    RETURN = "return"  # PX4 AUTO.RTL: fly home at the current altitude, land there


class Failsafe(enum.Enum):
    """What happens when the setpoint stream stops."""

    LEAVE_TO_HOLD = "leave_to_hold"  # PX4: leave OFFBOARD after COM_OF_LOSS_T, hold position
    BRAKE_IN_PLACE = "brake_in_place"  # ArduPilot: stay GUIDED, brake to zero after GUID_TIMEOUT


@dataclass(frozen=True)
class ModeSpec:
    name: str
    custom_mode: int
    behaviour: Behaviour
    needs_position: bool = False  # ArduPilot `requires_GPS()`: no arming (or entering it armed) without a position
    base_flags: int | None = None  # HEARTBEAT base_mode bits in this mode (None: the personality's base_mode_flags)


@dataclass(frozen=True)
class BootTimeline:
    """When a real autopilot gets ready, in seconds of its own clock after its link came up.

    Measured on ArduCopter 4.7 SITL (docs/CONFORMANCE.md); an emulator booting "real" follows
    it in sim time, a client must wait this long for home and position.
    """

    texts: tuple[tuple[float, str], ...]  # STATUSTEXTs at their instants
    ready_s: float  # the heartbeat leaves MAV_STATE_BOOT
    attitude_s: float  # the EKF is initialised: arming possible in modes without a position
    origin_s: float  # EKF origin and home set: HOME_POSITION and GPS_GLOBAL_ORIGIN exist
    position_s: float  # the EKF uses GPS: LOCAL_POSITION_NED, GLOBAL_POSITION_INT, arming in GUIDED


@dataclass(frozen=True)
class Answers:
    """The MAV_RESULTs where PX4 and ArduPilot answer the same command differently
    (ArduPilot: GCS_Common.cpp, checked against a real ArduCopter by tests/conformance)."""

    refused: int  # a well-formed command the vehicle's state refuses (arm, disarm, takeoff, mode)
    bad_arm_param: int  # COMPONENT_ARM_DISARM with param1 neither 0 nor 1
    unknown_stream: int  # SET_MESSAGE_INTERVAL for a message it cannot stream
    unknown_request: int  # REQUEST_MESSAGE for a message it cannot send
    unavailable_request: int  # REQUEST_MESSAGE for a message that does not exist yet (home before origin)
    interval_param3_must_be_zero: bool  # SET_MESSAGE_INTERVAL param3 (reserved) other than 0: DENIED
    only_minus_one_stops: bool  # interval -1 stops a stream and other negatives are DENIED (else any < 0 stops)
    set_mode_message_acked: bool  # the legacy SET_MODE message gets a COMMAND_ACK
    disarm_in_air: int = dialect.MAV_RESULT_FAILED  # PX4: TEMPORARILY_REJECTED ("Disarming denied: not landed")


@dataclass(frozen=True)
class ParamSpec:
    """One exposed parameter. `key` names the emulator quantity it controls (SI units);
    the wire value is SI × `scale` (ArduPilot speaks cm and cm/s)."""

    name: str
    key: str
    param_type: int
    scale: float = 1.0


@dataclass(frozen=True)
class Personality:
    name: str
    autopilot: int  # MAV_AUTOPILOT_*
    modes: tuple[ModeSpec, ...]
    boot_mode: str
    hold_mode: str  # where PX4 goes after takeoff and on offboard loss
    stop_mode: str  # what an agent commands to stop and hold position (ArduPilot BRAKE, PX4 its hold mode)
    offboard_mode: str
    land_mode: str
    takeoff_mode: str | None  # None: takeoff happens inside the offboard (GUIDED) mode
    failsafe: Failsafe
    params: tuple[ParamSpec, ...]
    param_bytewise: bool  # integer params packed into the float's bits (PX4) or cast (ArduPilot)
    takeoff_alt_is_amsl: bool  # NAV_TAKEOFF param7: PX4 AMSL, ArduPilot relative to home
    takeoff_needs_offboard_mode: bool  # ArduPilot only takes off in GUIDED
    # -- quirks the emulator (and the client's mode commands) follow
    set_mode_main_sub: bool  # DO_SET_MODE param2/param3 = PX4 main/sub mode; else param2 = custom_mode
    offboard_needs_stream: bool  # PX4 refuses OFFBOARD unless setpoints already stream
    offboard_from_ground: bool  # PX4 follows setpoints on the ground; ArduPilot GUIDED needs a takeoff first
    offboard_timeout_s: float  # default setpoint-loss timeout (COM_OF_LOSS_T / GUID_TIMEOUT)
    land_speed_mps: float  # default final descent speed (MPC_LAND_SPEED / LAND_SPEED), capped by the airframe
    answers: Answers
    base_mode_flags: int  # HEARTBEAT base_mode bits besides SAFETY_ARMED
    arm_texts: tuple[str, str]  # STATUSTEXT on arming, on disarming
    boot_timeline: BootTimeline | None  # measured start-up of the real one (None: not measured)
    # Message ids a signing vehicle still accepts unsigned (or badly signed): reports from
    # radios and traffic receivers that cannot sign, never a command. ArduPilot:
    # accept_unsigned_callback in GCS_Signing.cpp; PX4: unsigned_messages in mavlink_sign_control.cpp.
    accept_unsigned: tuple[int, ...] = ()
    # SETUP_SIGNING is refused while armed (ArduPilot: "ERROR: Won't setup signing when armed")
    setup_signing_disarmed_only: bool = False
    # -- measured on PX4 SITL with SIH (docs/CONFORMANCE.md, "PX4"); the defaults are ArduPilot's
    # An acceleration-only setpoint is a pure feed-forward in PX4's position controller (no
    # velocity loop closes around it), so the airframe's drag decelerates the vehicle: SIH's
    # linear drag SIH_KDV / SIH_MASS = 1 /s. ArduCopter integrates it into a velocity target.
    accel_drag_per_s: float = 0.0
    takeoff_speed_mps: float | None = None  # climb of the take-off mode (PX4 MPC_TKO_SPEED); None: the max climb
    takeoff_spoolup_s: float = 0.0  # from the take-off command to the climb (PX4: spool-up and ramp)
    # PX4 NAV_MC_ALT_RAD: a multicopter's take-off is reached once it is above the target minus
    # this, climbing or not (navigator/mission_block.cpp); it then loiters at the take-off's
    # setpoint, and real SIH has been seen to hold 0.6 m short of it. None: within
    # TAKEOFF_DONE_M of the target and level (ArduPilot).
    takeoff_alt_accept_m: float | None = None
    # The setpoint-loss failsafe's mode for each value of the offboard-loss action parameter
    # (PX4 COM_OBL_RC_ACT; without RC, 0-3 end in RTL); empty: hold_mode.
    loss_modes: tuple[str, ...] = ()
    loss_text: str = "Offboard lost: position hold"
    # PX4's commander takes any mode while disarmed (the user's intention: OFFBOARD without a
    # setpoint stream too); armed, OFFBOARD without one is ACCEPTED and nothing changes.
    mode_change_disarmed_accepted: bool = False
    takeoff_disarmed_accepted: bool = False  # PX4: NAV_TAKEOFF disarmed switches to AUTO.TAKEOFF; arming climbs
    # A failsafe that wants a mode needing a position (hold, return) while the GPS is lost
    # takes this one instead (PX4: ALTCTL, measured), and the GPS back takes `gps_back_mode`
    # (PX4: AUTO.RTL, its failsafe's return now that it can). None: no such fallback.
    no_position_mode: str | None = None
    gps_back_mode: str | None = None
    # A motor failure: what the autopilot says when it stops (PX4's failure detector), and
    # when the vehicle hits the ground (ArduPilot SITL); whether MAV_CMD_INJECT_FAILURE
    # (PX4's own fault injection, SYS_FAILURE_EN 1 in SITL) can stop a motor.
    motor_failure_texts: tuple[str, ...] = ()
    crash_texts: tuple[str, ...] = ("SIM Hit ground", "Potential Thrust Loss (1)")
    inject_failure: bool = False
    # Names of the autopilot's other modes (custom_mode -> name), which the emulator does not
    # fly but a real one may show (a failsafe's, a pilot's): logs and events name them.
    other_mode_names: tuple[tuple[int, str], ...] = ()

    def mode(self, name: str) -> ModeSpec:
        for m in self.modes:
            if m.name == name:
                return m
        raise KeyError(f"{self.name} has no mode {name!r}")

    def mode_by_custom(self, custom_mode: int) -> ModeSpec | None:
        for m in self.modes:
            if m.custom_mode == custom_mode:
                return m
        return None

    def mode_name(self, custom_mode: int) -> str | None:
        """The name of `custom_mode`, flown by the emulator or not (None: not one of ours)."""
        spec = self.mode_by_custom(custom_mode)
        if spec is not None:
            return spec.name
        return dict(self.other_mode_names).get(custom_mode)

    def custom_mode_from_set_mode(self, p2: float, p3: float) -> int:
        """custom_mode requested by MAV_CMD_DO_SET_MODE (param2, param3)."""
        if self.set_mode_main_sub:
            sub = 0 if p3 != p3 else int(p3)  # NaN (unset) means no sub mode
            return px4_custom_mode(int(p2), sub)
        return int(p2)

    def set_mode_params(self, name: str) -> tuple[float, float]:
        """(param2, param3) of MAV_CMD_DO_SET_MODE for mode `name` (client side)."""
        cm = self.mode(name).custom_mode
        if self.set_mode_main_sub:
            return float((cm >> 16) & 0xFF), float((cm >> 24) & 0xFF)
        return float(cm), 0.0


def px4_custom_mode(main_mode: int, sub_mode: int = 0) -> int:
    """PX4 packs {uint16 reserved; uint8 main_mode; uint8 sub_mode} into custom_mode."""
    return ((main_mode & 0xFF) << 16) | ((sub_mode & 0xFF) << 24)


_REAL32 = dialect.MAV_PARAM_TYPE_REAL32
# PX4's HEARTBEAT (streams/HEARTBEAT.hpp): CUSTOM_MODE always; STABILIZE with attitude control;
# MANUAL_INPUT in manual modes; AUTO | GUIDED | STABILIZE in auto modes (measured: AUTO.* 29,
# OFFBOARD 17, +128 armed).
_PX4_OFFBOARD = dialect.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | dialect.MAV_MODE_FLAG_STABILIZE_ENABLED
_PX4_MANUAL = _PX4_OFFBOARD | dialect.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED

PX4 = Personality(
    name="px4",
    autopilot=dialect.MAV_AUTOPILOT_PX4,
    modes=(
        ModeSpec("MANUAL", px4_custom_mode(1), Behaviour.HOLD, base_flags=_PX4_MANUAL),
        ModeSpec("ALTCTL", px4_custom_mode(2), Behaviour.HOLD, base_flags=_PX4_MANUAL),
        ModeSpec("POSCTL", px4_custom_mode(3), Behaviour.HOLD, base_flags=_PX4_MANUAL),
        ModeSpec("AUTO.TAKEOFF", px4_custom_mode(4, 2), Behaviour.TAKEOFF),
        ModeSpec("AUTO.LOITER", px4_custom_mode(4, 3), Behaviour.HOLD),
        ModeSpec("AUTO.RTL", px4_custom_mode(4, 5), Behaviour.RETURN),
        ModeSpec("AUTO.LAND", px4_custom_mode(4, 6), Behaviour.LAND),
        ModeSpec("OFFBOARD", px4_custom_mode(6), Behaviour.OFFBOARD, base_flags=_PX4_OFFBOARD),
        ModeSpec("STABILIZED", px4_custom_mode(7), Behaviour.HOLD, base_flags=_PX4_MANUAL),
    ),
    boot_mode="AUTO.LOITER",
    hold_mode="AUTO.LOITER",
    stop_mode="AUTO.LOITER",
    offboard_mode="OFFBOARD",
    land_mode="AUTO.LAND",
    takeoff_mode="AUTO.TAKEOFF",
    failsafe=Failsafe.LEAVE_TO_HOLD,
    params=(
        ParamSpec("COM_OBL_RC_ACT", "offboard_loss_action", dialect.MAV_PARAM_TYPE_INT32),
        ParamSpec("COM_OF_LOSS_T", "offboard_timeout_s", _REAL32),
        ParamSpec("MAV_SYS_ID", "sysid", dialect.MAV_PARAM_TYPE_INT32),
        ParamSpec("MIS_TAKEOFF_ALT", "takeoff_alt_m", _REAL32),
        ParamSpec("MPC_ACC_HOR_MAX", "max_accel_mps2", _REAL32),
        ParamSpec("MPC_LAND_SPEED", "land_speed_mps", _REAL32),
        ParamSpec("MPC_TKO_SPEED", "takeoff_speed_mps", _REAL32),
        ParamSpec("NAV_MC_ALT_RAD", "takeoff_alt_accept_m", _REAL32),
        # SIH's linear drag (N s/m on its 1 kg airframe: 1 /s); 0 flies the twin's drag-free mass
        ParamSpec("SIH_KDV", "accel_drag_per_s", _REAL32),
        ParamSpec("MPC_XY_VEL_MAX", "max_speed_mps", _REAL32),
        # SIH's GPS (sensor_gps_sim): satellites used; below 4 it reports no fix. The GPS
        # loss a PX4 SIH is given (MAV_CMD_INJECT_FAILURE's GPS unit is not SIH's).
        ParamSpec("SIM_GPS_USED", "gps_satellites", dialect.MAV_PARAM_TYPE_INT32),
        ParamSpec("MPC_Z_VEL_MAX_UP", "max_climb_mps", _REAL32),
    ),
    param_bytewise=True,
    takeoff_alt_is_amsl=True,
    takeoff_needs_offboard_mode=False,
    # -- quirks
    set_mode_main_sub=True,
    offboard_needs_stream=True,
    offboard_from_ground=True,
    offboard_timeout_s=1.0,
    land_speed_mps=0.7,
    answers=Answers(
        refused=dialect.MAV_RESULT_DENIED,
        bad_arm_param=dialect.MAV_RESULT_DENIED,
        unknown_stream=dialect.MAV_RESULT_UNSUPPORTED,
        unknown_request=dialect.MAV_RESULT_UNSUPPORTED,
        unavailable_request=dialect.MAV_RESULT_DENIED,
        interval_param3_must_be_zero=False,
        only_minus_one_stops=False,
        set_mode_message_acked=True,
        disarm_in_air=dialect.MAV_RESULT_TEMPORARILY_REJECTED,
    ),
    # PX4 SITL, measured in AUTO.LOITER, AUTO.TAKEOFF, AUTO.RTL: 29 (157 armed)
    base_mode_flags=(
        dialect.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | dialect.MAV_MODE_FLAG_AUTO_ENABLED
        | dialect.MAV_MODE_FLAG_GUIDED_ENABLED | dialect.MAV_MODE_FLAG_STABILIZE_ENABLED
    ),
    arm_texts=("Armed by external command", "Disarmed by external command"),
    # PX4 SITL with SIH: position at 0.5-0.9 s, home at 1.2-2.2 s, "Ready for takeoff!" (arming
    # possible, heartbeat STANDBY instead of UNINIT) at ~4.5 s, measured from the process start.
    boot_timeline=BootTimeline(
        texts=(),  # PX4 logs "Ready for takeoff!" but sends no STATUSTEXT for it
        ready_s=4.5,
        attitude_s=4.5,
        origin_s=1.2,
        position_s=0.6,
    ),
    accept_unsigned=(dialect.MAVLINK_MSG_ID_RADIO_STATUS, dialect.MAVLINK_MSG_ID_ADSB_VEHICLE,
                     dialect.MAVLINK_MSG_ID_COLLISION),
    accel_drag_per_s=1.0,
    takeoff_speed_mps=1.5,
    takeoff_spoolup_s=3.5,
    takeoff_alt_accept_m=0.8,  # NAV_MC_ALT_RAD's default
    loss_modes=("AUTO.RTL", "AUTO.RTL", "AUTO.RTL", "AUTO.RTL", "AUTO.LAND", "AUTO.LOITER"),
    loss_text="Failsafe activated",
    no_position_mode="ALTCTL",
    gps_back_mode="AUTO.RTL",
    # measured 0.8 s after the injection, severity CRITICAL; nothing at the ground
    motor_failure_texts=("Preflight Fail: Attitude failure (roll)",),
    crash_texts=(),
    inject_failure=True,
    mode_change_disarmed_accepted=True,
    takeoff_disarmed_accepted=True,
    # px4_custom_mode.h (src/modules/commander)
    other_mode_names=(
        (px4_custom_mode(3, 1), "POSCTL.ORBIT"), (px4_custom_mode(3, 2), "POSCTL.SLOW"),
        (px4_custom_mode(4, 1), "AUTO.READY"), (px4_custom_mode(4, 4), "AUTO.MISSION"),
        (px4_custom_mode(4, 8), "AUTO.FOLLOW_TARGET"), (px4_custom_mode(4, 9), "AUTO.PRECLAND"),
        (px4_custom_mode(4, 10), "AUTO.VTOL_TAKEOFF"), (px4_custom_mode(5), "ACRO"),
        (px4_custom_mode(8), "RATTITUDE"), (px4_custom_mode(10), "TERMINATION"),
        (px4_custom_mode(11), "ALTITUDE_CRUISE"),
    ),
)

ARDUPILOT = Personality(
    name="ardupilot",
    autopilot=dialect.MAV_AUTOPILOT_ARDUPILOTMEGA,
    modes=(
        ModeSpec("STABILIZE", 0, Behaviour.HOLD),
        ModeSpec("ALT_HOLD", 2, Behaviour.HOLD),
        ModeSpec("GUIDED", 4, Behaviour.OFFBOARD, needs_position=True),
        ModeSpec("LOITER", 5, Behaviour.HOLD, needs_position=True),
        ModeSpec("LAND", 9, Behaviour.LAND),
        ModeSpec("POSHOLD", 16, Behaviour.HOLD, needs_position=True),
        ModeSpec("BRAKE", 17, Behaviour.BRAKE, needs_position=True),
    ),
    boot_mode="STABILIZE",
    hold_mode="LOITER",
    stop_mode="BRAKE",
    offboard_mode="GUIDED",
    land_mode="LAND",
    takeoff_mode=None,
    failsafe=Failsafe.BRAKE_IN_PLACE,
    params=(
        ParamSpec("GUID_TIMEOUT", "offboard_timeout_s", _REAL32),
        ParamSpec("LAND_SPEED", "land_speed_mps", dialect.MAV_PARAM_TYPE_INT16, 100.0),
        ParamSpec("PILOT_TKOFF_ALT", "takeoff_alt_m", _REAL32, 100.0),
        ParamSpec("MAV_SYSID", "sysid", dialect.MAV_PARAM_TYPE_INT16),  # SYSID_THISMAV before 4.7
        ParamSpec("WPNAV_ACCEL", "max_accel_mps2", _REAL32, 100.0),
        ParamSpec("WPNAV_SPEED", "max_speed_mps", _REAL32, 100.0),
        ParamSpec("WPNAV_SPEED_UP", "max_climb_mps", _REAL32, 100.0),
    ),
    param_bytewise=False,
    takeoff_alt_is_amsl=False,
    takeoff_needs_offboard_mode=True,
    # -- quirks
    set_mode_main_sub=False,
    offboard_needs_stream=False,
    offboard_from_ground=False,
    offboard_timeout_s=3.0,
    land_speed_mps=0.5,
    answers=Answers(
        refused=dialect.MAV_RESULT_FAILED,
        bad_arm_param=dialect.MAV_RESULT_UNSUPPORTED,
        unknown_stream=dialect.MAV_RESULT_DENIED,
        unknown_request=dialect.MAV_RESULT_FAILED,
        unavailable_request=dialect.MAV_RESULT_ACCEPTED,  # queued; sent once it exists
        interval_param3_must_be_zero=True,
        only_minus_one_stops=True,
        set_mode_message_acked=False,
    ),
    # ArduCopter's base_mode(): STABILIZE, GUIDED (position controller active), MANUAL_INPUT, CUSTOM_MODE
    base_mode_flags=(
        dialect.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | dialect.MAV_MODE_FLAG_GUIDED_ENABLED
        | dialect.MAV_MODE_FLAG_STABILIZE_ENABLED | dialect.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
    ),
    arm_texts=("Arming motors", "Disarming motors"),  # what ArduPilot's SITL build says
    boot_timeline=BootTimeline(
        texts=(
            (1.4, "ArduPilot Ready"),
            (3.4, "EKF3 IMU0 initialised"),
            (3.4, "AHRS: EKF3 active"),
            (19.0, "EKF3 IMU0 origin set"),
            (40.0, "EKF3 IMU0 is using GPS"),
        ),
        ready_s=1.4,
        attitude_s=3.4,
        origin_s=19.0,
        position_s=40.0,
    ),
    accept_unsigned=(dialect.MAVLINK_MSG_ID_RADIO_STATUS, dialect.MAVLINK_MSG_ID_RADIO),
    setup_signing_disarmed_only=True,
)

PERSONALITIES = {p.name: p for p in (PX4, ARDUPILOT)}


def personality(name: str) -> Personality:
    """The personality called `name`; an unknown name is a UserError listing the known ones."""
    try:
        return PERSONALITIES[name]
    except KeyError:
        raise UserError(f"unknown autopilot {name!r} (known: {', '.join(PERSONALITIES)})") from None


def personality_for_autopilot(autopilot: int) -> Personality:
    """The personality a client should assume for a HEARTBEAT's autopilot field.

    Anything but the autopilots we know is an error: guessing would command modes by numbers
    that mean something else to that firmware.
    """
    for p in PERSONALITIES.values():
        if p.autopilot == autopilot:
            return p
    known = ", ".join(f"{p.name} ({enum_name('MAV_AUTOPILOT', p.autopilot)})" for p in PERSONALITIES.values())
    raise UserError(f"the vehicle's heartbeat names autopilot {enum_name('MAV_AUTOPILOT', autopilot)}; known: {known}")
