"""One emulated autopilot: mode/arming state machine, setpoints and failsafes.

The vehicle never integrates its own motion: the fleet steps all vehicles' physics in one
batched call and this class only decides *what each vehicle is trying to do* (the guidance
kind and target, written into its row of the `Fleet`) and reacts to what happened (takeoff
reached, touchdown, setpoint loss). Message parsing and replies live in `handlers.py`;
telemetry builders in `telemetry.py`.
"""

from __future__ import annotations

import logging
import math
import random
import struct
import time
from collections import OrderedDict
from collections.abc import Callable
from typing import TYPE_CHECKING, BinaryIO

from plmarl_sitl.config import VehicleModel
from plmarl_sitl.deploy.mavlink.codec import Codec, Fields, Message, dialect
from plmarl_sitl.deploy.mavlink.personality import Behaviour, Failsafe, ModeSpec, Personality
from plmarl_sitl.deploy.mavlink.wire import ACCEL_ONLY, POSITION_ONLY, VELOCITY_ONLY
from plmarl_sitl.model.events import GPS_OUT_AFTER_S, GPS_STREAM_STOPS_S
from plmarl_sitl.model.geodesy import ned_to_geodetic
from plmarl_sitl.sitl.autopilot.counters import InputCounters
from plmarl_sitl.sitl.autopilot.fleet import Fleet
from plmarl_sitl.sitl.autopilot.guidance import Kind
from plmarl_sitl.sitl.autopilot.params import ParamStore

if TYPE_CHECKING:
    import asyncio

log = logging.getLogger("plmarl.autopilot")
d = dialect

ACCEPTED = d.MAV_RESULT_ACCEPTED
DENIED = d.MAV_RESULT_DENIED
TEMP_REJECTED = d.MAV_RESULT_TEMPORARILY_REJECTED

LAND_SLOW_BELOW_M = 10.0  # PX4 MPC_LAND_ALT1 / ArduPilot LAND_ALT_LOW: slow down near ground
# PX4 AUTO.TAKEOFF climbs at MPC_TKO_SPEED below MPC_LAND_ALT1, then at MPC_Z_V_AUTO_UP
# (FlightTaskAuto::_updateTrajConstraints); measured on SIH: 1.45 m/s, then 3.0 m/s.
PX4_AUTO_CLIMB_MPS = 3.0
RETURNED_M = 0.5  # RTL: this close to home (horizontally), it lands
TAKEOFF_DONE_M = 0.3
MAX_PEERS = 8
_TLOG_STAMP = struct.Struct(">Q")  # a .tlog record: big-endian unix time in us, then the frame
_MAVLINK_MAGIC = (b"\xfd", b"\xfe")  # the first byte of a MAVLink 2 / 1 frame
# SETUP_SIGNING: a vehicle's signing timestamp starts this far past the one given (10 us
# ticks), as ArduPilot's load_signing_key does against replays across a reboot.
SETUP_SIGNING_AHEAD = 60 * 100_000
# POSITION_TARGET_LOCAL_NED's type_mask for what the vehicle tracks (a landing: a velocity).
# Enum members as module constants for the per-substep state machine (see fleet.py).
_IDLE, _LAND, _FALL, _TOUCHDOWN = Kind.IDLE, Kind.LAND, Kind.FALL, Kind.TOUCHDOWN
ECHO_MASK = {Kind.POSITION: POSITION_ONLY, Kind.VELOCITY: VELOCITY_ONLY, Kind.ACCEL: ACCEL_ONLY, Kind.LAND: VELOCITY_ONLY}


class Vehicle:
    """State of vehicle `index` of a fleet (sysid = index + 1 unless configured).

    `home_geodetic` is (lat, lon, alt) of its home, the origin of its local NED frame; `gcs`
    a ground station that gets its telemetry besides its peers; `heartbeat` builds the
    HEARTBEAT it sends at once on a mode or arming change (`telemetry.heartbeat`).
    """

    def __init__(
        self,
        fleet: Fleet,
        index: int,
        sysid: int,
        personality: Personality,
        model: VehicleModel,
        home_geodetic: tuple[float, float, float],
        *,
        gcs: tuple[str, int] | None,
        signing_key: bytes | None,
        heartbeat: Callable[[Vehicle], Message],
    ) -> None:
        self.fleet = fleet
        self.index = index
        self.personality = personality
        self.model = model
        self.codec = Codec(sysid, d.MAV_COMP_ID_AUTOPILOT1, signing_key, personality.accept_unsigned)
        self.params = ParamStore(model, personality, sysid)
        self.counters = InputCounters()
        self.home_geodetic = home_geodetic
        self.gcs = gcs
        self._heartbeat = heartbeat
        self.transport: asyncio.DatagramTransport | None = None
        self.peers: OrderedDict[tuple[str, int], None] = OrderedDict()
        self.killed = False
        self.gnss_noise_std_m = 0.0
        # Autopilot faults (gps_loss, motor_failure mission events): see "autopilot faults" below.
        self.gps_lost_at: float | None = None
        self.ekf_failsafe = False
        self.aiding_stopped = False  # the EKF has no position: LOCAL_POSITION_NED stops
        self.motor_failed = False
        self.texts: list[tuple[float, str]] | None = None  # STATUSTEXTs kept for the world (None: not kept)
        self._noise_rng = random.Random(sysid)
        self.tlog: BinaryIO | None = None  # every message sent and received, as a .tlog
        self._armed = False
        self._mode_spec: ModeSpec = personality.mode(personality.boot_mode)
        self._yaw = 0.0
        # Last external setpoint: (guidance kind, vector, type_mask) and when it arrived.
        self.setpoint: tuple[Kind, tuple[float, float, float], int] | None = None
        self.setpoint_time = -math.inf
        self.setpoint_timed_out = False  # ArduPilot: braked after GUID_TIMEOUT until the next one
        self.taking_off = False
        self._takeoff_alt = 0.0
        self._climb_at = 0.0  # sim time the take-off climb starts (after the spool-up)
        self.returning = False  # PX4 AUTO.RTL on its way home
        self.failsafe = False  # a failsafe chose the mode (PX4: heartbeat CRITICAL until a new mode)
        self._apply_limits()

    # ------------------------------------------------------------------ identity / state
    @property
    def sysid(self) -> int:
        return self.codec.sysid

    @property
    def armed(self) -> bool:
        return self._armed

    @armed.setter
    def armed(self, value: bool) -> None:
        if value != self._armed:
            self._armed = value
            self._refresh_deadline()
            self._announce_state()

    @property
    def mode_spec(self) -> ModeSpec:
        return self._mode_spec

    @mode_spec.setter
    def mode_spec(self, spec: ModeSpec) -> None:
        if spec != self._mode_spec:
            self._mode_spec = spec
            self._refresh_deadline()
            self._announce_state()

    def _refresh_deadline(self) -> None:
        """Publish when this vehicle's setpoint stream times out (inf: no timeout armed).

        The fleet compares all deadlines with the clock in one numpy call per substep, so
        vehicles that are simply flying setpoints cost nothing per substep.
        """
        dl = math.inf
        if (
            self._mode_spec.behaviour == Behaviour.OFFBOARD
            and self._armed
            and self.setpoint is not None
            and not self.setpoint_timed_out
            and not self.killed
        ):
            dl = self.setpoint_time + self.params["offboard_timeout_s"]
        self.fleet.set_deadline(self.index, dl)

    def _announce_state(self) -> None:
        """Send a HEARTBEAT right away on a mode or arming change, and log it (INFO: the
        `-v` of `plmarl autopilot`, the world's log in a swarm).

        Clients learn the mode only from heartbeats (1 Hz); without this a failsafe would
        look up to a second late to MAVSDK, which judges offboard loss to within 0.5 s.
        """
        log.info("vehicle %d: %s, %s, %.1f m", self.sysid, self._mode_spec.name, "armed" if self._armed else "disarmed",
                 self.altitude() + 0.0)
        self.send(self._heartbeat(self))

    @property
    def mode(self) -> str:
        return self.mode_spec.name

    @property
    def custom_mode(self) -> int:
        return self.mode_spec.custom_mode

    @property
    def behaviour(self) -> Behaviour:
        return self.mode_spec.behaviour

    # Rows as Python floats in one `tolist` (the same values as float() of each element, at
    # a third of the cost: every telemetry message and state-machine step reads them).
    def position(self) -> tuple[float, float, float]:
        x, y, z = self.fleet.pos_np[self.index].tolist()
        return x, y, z

    def velocity(self) -> tuple[float, float, float]:
        x, y, z = self.fleet.vel_np[self.index].tolist()
        return x, y, z

    def last_accel(self) -> tuple[float, float, float]:
        x, y, z = self.fleet.acc_np[self.index].tolist()
        return x, y, z

    def altitude(self) -> float:
        return self.fleet.altitude(self.index)

    def nav_position(self) -> tuple[float, float, float]:
        """The position the navigation filter reports: truth plus GNSS noise (if set by a
        gnss_noise mission event), redrawn per message like a real receiver's jitter."""
        x, y, z = self.position()
        std = self.gnss_noise_std_m
        if std > 0:
            x, y, z = (c + self._noise_rng.gauss(0.0, std) for c in (x, y, z))
        return x, y, z

    def geodetic(self) -> tuple[float, float, float]:
        x, y, z = self.nav_position()
        lat, lon, alt = self.home_geodetic
        return ned_to_geodetic(lat, lon, alt, x, y, z)

    @property
    def yaw(self) -> float:
        """Heading: a multirotor flying a point-mass path faces where it goes."""
        vx, vy, _ = self.velocity()
        if vx * vx + vy * vy > 1.0:
            self._yaw = math.atan2(vy, vx)
        return self._yaw

    @property
    def landed_state(self) -> int:
        if self.taking_off:
            return d.MAV_LANDED_STATE_TAKEOFF
        if int(self.fleet.guidance.kind[self.index]) == Kind.LAND:
            return d.MAV_LANDED_STATE_LANDING
        return d.MAV_LANDED_STATE_ON_GROUND if self.on_ground() else d.MAV_LANDED_STATE_IN_AIR

    def on_ground(self) -> bool:
        return self.fleet.on_ground(self.index)

    # ------------------------------------------------------------------ output
    def send(self, msg: Message | Fields | None, addr: tuple[str, int] | None = None) -> None:
        """Send to `addr`, or to every peer and the ground station (telemetry)."""
        t = self.transport
        if msg is None or t is None or self.killed or t.is_closing():
            return
        buf = self.codec.encode(msg)
        self.record(buf)
        if addr is not None:
            t.sendto(buf, addr)
        else:
            self._broadcast(t, buf)

    def send_bundle(self, msgs: list[Message | Fields | None]) -> None:
        """Telemetry due together, to every peer and the ground station in one datagram
        (MAVLink over UDP allows several frames per datagram; PX4 sends them so)."""
        t = self.transport
        if t is None or self.killed or t.is_closing():
            return
        encode = self.codec.encode
        frames = [encode(m) for m in msgs if m is not None]
        if not frames:
            return
        if self.tlog is not None:
            self.record_all(frames)
        self._broadcast(t, frames[0] if len(frames) == 1 else b"".join(frames))

    def _broadcast(self, t: asyncio.DatagramTransport, buf: bytes) -> None:
        """One datagram to every peer and to the ground station."""
        for peer in self.peers:
            t.sendto(buf, peer)
        gcs = self.gcs
        if gcs is not None and gcs not in self.peers:
            t.sendto(buf, gcs)

    def record(self, raw: bytes) -> None:
        """Append one MAVLink frame (or datagram) to the .tlog (`record_all`)."""
        self.record_all([raw])

    def record_all(self, frames: list[bytes]) -> None:
        """Append MAVLink frames to the .tlog, each as 8-byte big-endian unix time in us, then
        the frame (the format pymavlink and MAVExplorer read): one clock reading and one write
        for the frames of one datagram; anything not a MAVLink frame is left out."""
        if self.tlog is not None:
            stamp = _TLOG_STAMP.pack(int(time.time() * 1e6))
            # stamp + f1 + stamp + f2 ...: the stamp as the separator after an empty first item
            self.tlog.write(stamp.join([b"", *(f for f in frames if f[:1] in _MAVLINK_MAGIC)]))

    def statustext(self, text: str, severity: int = d.MAV_SEVERITY_INFO) -> None:
        if self.texts is not None:
            self.texts.append((self.fleet.now, text))
        self.send(self.codec.mav.statustext_encode(severity, text[:50].encode()))

    def remember_peer(self, addr: tuple[str, int]) -> None:
        peers = self.peers
        if addr in peers:
            peers.move_to_end(addr)
            return
        peers[addr] = None
        if len(peers) > MAX_PEERS:
            peers.popitem(last=False)

    def setup_signing(self, key: bytes, initial_timestamp: int) -> None:
        """SETUP_SIGNING: sign with `key` from now on (an all-zero key and timestamp: stop
        signing), as ArduPilot's handle_setup_signing and PX4's MavlinkSignControl do."""
        if initial_timestamp == 0 and not any(key):
            self.codec.clear_signing_key()
            log.warning("vehicle %d: MAVLink signing disabled by SETUP_SIGNING", self.sysid)
            return
        self.codec.set_signing_key(key)
        self.codec.mav.signing.timestamp = initial_timestamp + SETUP_SIGNING_AHEAD
        log.info("vehicle %d: MAVLink signing key set by SETUP_SIGNING", self.sysid)

    def drop(self, fault: str, detail: str = "") -> None:
        """Count a dropped input; the first of each kind is logged and announced."""
        if self.counters.add(fault):
            log.warning("vehicle %d: dropped %s input%s (first occurrence)", self.sysid, fault, f": {detail}" if detail else "")
            self.statustext(f"Dropped {fault} input", d.MAV_SEVERITY_WARNING)

    # ------------------------------------------------------------------ guidance
    def _apply_limits(self) -> None:
        g = self.fleet.guidance
        i = self.index
        g.max_speed[i, 0] = self.params["max_speed_mps"]
        g.max_accel[i, 0] = self.params["max_accel_mps2"]
        g.drag[i] = self.params["accel_drag_per_s"]

    def params_changed(self) -> None:
        self._apply_limits()
        self._refresh_deadline()
        if self.taking_off:
            self.fleet.guidance.max_speed[self.index, 0] = self.params["max_climb_mps"]

    def _guide(self, kind: Kind, target: tuple[float, float, float] | None = None) -> None:
        if self.motor_failed:  # whatever it is asked, a quadrotor with a dead motor falls, or lies where it fell
            kind, target = (Kind.IDLE if self.on_ground() else Kind.FALL), None
        self.fleet.guide(self.index, kind, target, watch=self.taking_off or self.returning)
        self._apply_limits()

    def _hold_here(self) -> None:
        """Brake at half the acceleration limit and hold where the vehicle stops."""
        if self.on_ground() and not self.taking_off:
            self._guide(Kind.IDLE)
            return
        x, y, z = self.position()
        vx, vy, vz = self.velocity()
        speed = math.sqrt(vx * vx + vy * vy + vz * vz)
        k = speed / self.params["max_accel_mps2"]  # stopping distance v^2 / a, along v
        self._guide(Kind.POSITION, (x + vx * k, y + vy * k, min(z + vz * k, 0.0)))

    def active_target(self) -> tuple[int, tuple[float, float, float]] | None:
        """(type_mask, vector) of what the vehicle is tracking, for POSITION_TARGET_LOCAL_NED."""
        g = self.fleet.guidance
        kind = Kind(int(g.kind[self.index]))
        mask = ECHO_MASK.get(kind)
        if mask is None:
            return None
        t = g.target[self.index]
        if kind == Kind.LAND:
            return mask, (0.0, 0.0, float(g.descent[self.index]))
        return mask, (float(t[0]), float(t[1]), float(t[2]))

    def _apply_setpoint(self) -> None:
        assert self.setpoint is not None
        kind, vec, _ = self.setpoint
        self.taking_off = False
        self._guide(kind, vec)

    def _offboard_in_control(self) -> bool:
        """Whether external setpoints drive the vehicle right now."""
        if self.behaviour != Behaviour.OFFBOARD or not self.armed:
            return False
        return self.personality.offboard_from_ground or not (self.on_ground() and not self.taking_off)

    # ------------------------------------------------------------------ actions
    def _position_ok(self) -> bool:
        """Whether the navigation filter has a position (late on the real boot timeline; gone
        once the EKF stops aiding after a GPS loss)."""
        return self.fleet.boot.position(self.fleet.now) and not self.aiding_stopped

    def set_mode(self, spec: ModeSpec) -> int:
        if spec.behaviour == Behaviour.TAKEOFF:
            return self.takeoff(None)
        if spec.behaviour == Behaviour.OFFBOARD and self.personality.offboard_needs_stream:
            if self._setpoint_stale():
                if not self.personality.mode_change_disarmed_accepted:
                    return TEMP_REJECTED
                # PX4 (measured): disarmed, any mode is taken (the heartbeat says OFFBOARD);
                # armed, ACCEPTED all the same, but the mode stays and it says why.
                if self.armed:
                    self.statustext("Switching to Offboard is currently not available", d.MAV_SEVERITY_CRITICAL)
                    return ACCEPTED
        if self.armed and spec.needs_position and not self._position_ok():
            self.statustext(f"Flight mode change failed: {spec.name} requires position", d.MAV_SEVERITY_WARNING)
            return self.personality.answers.refused
        self.failsafe = False
        self.mode_spec = spec
        self.taking_off = False
        self.returning = False
        self.setpoint_timed_out = False
        b = spec.behaviour
        if b == Behaviour.LAND:
            self._start_land()
        elif b == Behaviour.RETURN:
            self._start_return()
        elif b == Behaviour.OFFBOARD and self.setpoint is not None and self._offboard_in_control():
            self._apply_setpoint()
        elif self.armed:
            self._hold_here()
        self._refresh_deadline()
        return ACCEPTED

    def arm(self, force: bool) -> int:
        if self.armed:
            return ACCEPTED
        refused = self.personality.answers.refused
        if not force and not self.on_ground():
            return refused
        if not force and self.behaviour == Behaviour.LAND:
            return refused
        # ArduPilot runs these checks even with ARMING_CHECK 0 or a forced arm.
        if not self.fleet.boot.attitude(self.fleet.now):
            self.statustext("Arm: AHRS: EKF3 not started", d.MAV_SEVERITY_CRITICAL)
            return refused
        if self.mode_spec.needs_position and not self._position_ok():
            self.statustext("Arm: Need Position Estimate", d.MAV_SEVERITY_CRITICAL)
            return refused
        self.armed = True
        self.statustext(self.personality.arm_texts[0])
        if self.behaviour == Behaviour.TAKEOFF:  # PX4: a take-off asked for while disarmed starts now
            self._start_takeoff(self._takeoff_alt)
        elif self.behaviour == Behaviour.OFFBOARD and self.setpoint is not None and self._offboard_in_control():
            self._apply_setpoint()
        else:
            self._hold_here()
        return ACCEPTED

    def disarm(self, force: bool) -> int:
        if not self.armed:
            return ACCEPTED
        if not force and not self.on_ground():
            if self.personality.answers.disarm_in_air == TEMP_REJECTED:
                self.statustext("Disarming denied: not landed", d.MAV_SEVERITY_CRITICAL)
            return self.personality.answers.disarm_in_air
        self.armed = False
        self.taking_off = False
        self._guide(Kind.IDLE if self.on_ground() else Kind.FALL)
        self.statustext(self.personality.arm_texts[1])
        return ACCEPTED

    def takeoff(self, alt_rel_m: float | None) -> int:
        """Climb to `alt_rel_m` above home (None: the takeoff-altitude parameter)."""
        p = self.personality
        if not self.on_ground():
            return p.answers.refused
        if not self.armed and not p.takeoff_disarmed_accepted:
            return p.answers.refused
        if p.takeoff_needs_offboard_mode and self.behaviour != Behaviour.OFFBOARD:
            return p.answers.refused
        alt = self.params["takeoff_alt_m"] if alt_rel_m is None else alt_rel_m
        if alt <= self.altitude():  # ArduPilot: "can't takeoff downwards"
            return p.answers.refused
        if not 0.5 <= alt <= self.model.max_alt_m:
            self.drop("bad_value", f"takeoff altitude {alt:g} m")
            return DENIED
        if p.takeoff_mode is not None:
            self.failsafe = False
            self.mode_spec = p.mode(p.takeoff_mode)
        self._takeoff_alt = alt
        if self.armed:  # else (PX4): in AUTO.TAKEOFF, the climb starts when it is armed
            self._start_takeoff(alt)
        return ACCEPTED

    def _start_takeoff(self, alt: float) -> None:
        self.taking_off = True
        self.returning = False
        if self.on_ground():  # PX4: the motors spool up and the thrust ramps before the climb
            self._climb_at = self.fleet.now + self.personality.takeoff_spoolup_s
        x, y, _ = self.position()
        if self.fleet.now < self._climb_at:
            self._guide(Kind.IDLE)
        else:
            self._guide(Kind.POSITION, (x, y, -alt))
        self._climb_limit()

    def _climb_limit(self) -> None:
        """The take-off climb speed: the take-off speed near the ground (PX4), else the max climb."""
        speed = self.params["max_climb_mps"]
        if self.personality.takeoff_speed_mps is not None:
            low = self.altitude() < LAND_SLOW_BELOW_M
            speed = min(speed, self.params["takeoff_speed_mps"] if low else PX4_AUTO_CLIMB_MPS)
        self.fleet.guidance.max_speed[self.index, 0] = speed

    def land(self) -> int:
        if not self.armed:
            return self.personality.answers.refused
        self.failsafe = False
        self.mode_spec = self.personality.mode(self.personality.land_mode)
        self.taking_off = False
        self.returning = False
        self._start_land()
        return ACCEPTED

    def _start_land(self) -> None:
        if not self.armed or self.on_ground():
            self._guide(Kind.IDLE)
            return
        x, y, _ = self.position()
        self._guide(Kind.LAND, (x, y, 0.0))

    def _start_return(self) -> None:
        """PX4 AUTO.RTL, simplified: fly home at the current altitude, then land there."""
        if not self.armed or self.on_ground():
            self._guide(Kind.IDLE)
            return
        _, _, z = self.position()
        self.returning = True
        self._guide(Kind.POSITION, (0.0, 0.0, z))

    def accept_setpoint(self, kind: Kind, vec: tuple[float, float, float], type_mask: int) -> None:
        self.setpoint = (kind, vec, type_mask)
        self.setpoint_time = self.fleet.now
        self.setpoint_timed_out = False
        if self._offboard_in_control():
            self._apply_setpoint()
        self._refresh_deadline()

    def kill(self) -> None:
        """Node failure: the vehicle goes silent and, if flying, falls."""
        self.killed = True
        self.armed = False
        self.taking_off = False
        self._guide(Kind.IDLE if self.on_ground() else Kind.FALL)

    # ------------------------------------------------------------------ autopilot faults
    # What the real autopilots do, measured under an agent's acceleration setpoints
    # (docs/CONFORMANCE.md, "Autopilot faults"; the delays are model.events').
    # ArduCopter 4.7 (SIM_GPS1_ENABLE 0): it dead-reckons; GPS_OUT_AFTER_S later its EKF
    # failsafe switches to LAND; GPS_STREAM_STOPS_S later the EKF stops aiding and
    # LOCAL_POSITION_NED stops; it lands blind and disarms. GPS back: the EKF uses it again,
    # the stream resumes, the mode stays LAND.
    # PX4 1.17 SIH (SIM_GPS_USED 0): an acceleration-only OFFBOARD needs only an attitude,
    # so nothing changes: it stays in OFFBOARD, armed, its position streamed on (dead
    # reckoning; the real estimate drifts, this one does not). Only a failsafe that wants a
    # position (the setpoints stop) takes ALTCTL instead (heartbeat CRITICAL); the GPS back
    # then takes AUTO.RTL (measured: "Failsafe activated" 2.3 s, AUTO.RTL ~3 s later; here at once).
    # A motor failure (ArduCopter SIM_ENGINE_FAIL, PX4 INJECT_FAILURE with CA_FAILURE_MODE 1):
    # it falls, hits the ground and stays armed in its mode.
    def lose_gps(self) -> None:
        if self.gps_lost_at is None:
            self.gps_lost_at = self.fleet.now
            self.fleet.gps_lost.add(self.index)

    def restore_gps(self) -> None:
        if self.gps_lost_at is None:
            return
        self.gps_lost_at = None
        self.fleet.gps_lost.discard(self.index)
        if self.aiding_stopped or self.ekf_failsafe:
            self.statustext("EKF3 IMU0 is using GPS")
        if self.ekf_failsafe:
            self.statustext("EKF Failsafe Cleared", d.MAV_SEVERITY_CRITICAL)
        self.aiding_stopped = self.ekf_failsafe = False
        p = self.personality
        if p.gps_back_mode is not None and self.failsafe and self.mode == p.no_position_mode and self.armed:
            self.statustext(p.loss_text, d.MAV_SEVERITY_CRITICAL)
            self._enter_failsafe_mode(p.gps_back_mode)

    def gps_param_set(self, fix: bool) -> None:
        """PX4 SIH's SIM_GPS_USED set (the world's gps_loss on a real PX4 goes this way too)."""
        if fix:
            self.restore_gps()
        else:
            self.lose_gps()

    def gps_update(self, now: float) -> None:
        """The navigation filter's reaction to the GPS loss, as time goes on (called by the host)."""
        if self.gps_lost_at is None or self.killed:
            return
        lost_s = now - self.gps_lost_at
        out_s, stops_s = GPS_OUT_AFTER_S[self.personality.name], GPS_STREAM_STOPS_S[self.personality.name]
        if out_s is not None and not self.ekf_failsafe and lost_s >= out_s:
            self.ekf_failsafe = True
            self.statustext("EKF variance", d.MAV_SEVERITY_CRITICAL)
            if self.armed and (self.mode_spec.needs_position or self.behaviour == Behaviour.OFFBOARD):
                self.mode_spec = self.personality.mode(self.personality.land_mode)
                self.taking_off = False
                self._start_land()
                self.statustext("EKF Failsafe: changed to LAND Mode", d.MAV_SEVERITY_CRITICAL)
        if stops_s is not None and not self.aiding_stopped and lost_s >= stops_s:
            self.aiding_stopped = True
            self.statustext("EKF3 IMU0 stopped aiding")

    def fail_motor(self) -> None:
        if not self.motor_failed:
            for text in self.personality.motor_failure_texts:
                self.statustext(text, d.MAV_SEVERITY_CRITICAL)
        self.motor_failed = True
        self.taking_off = False
        self._guide(Kind.FALL)

    # ------------------------------------------------------------------ per substep
    def update(self, now: float) -> bool:
        """Takeoff/landing/falling progress after a physics substep. False: stop watching me.

        Ground contact is the fleet's (it turns the kind into TOUCHDOWN); setpoint loss is
        not checked here but through `_refresh_deadline`.
        """
        g = self.fleet.guidance
        kind = int(g.kind[self.index])
        if kind == _TOUCHDOWN:
            self._touchdown()
            return False
        if kind == _LAND:
            fast = self.params["max_climb_mps"]
            g.descent[self.index] = fast if self.altitude() > LAND_SLOW_BELOW_M else self.params["land_speed_mps"]
            return True
        if kind == _FALL:
            return True
        if self.returning:
            x, y, _ = self.position()
            if math.hypot(x, y) < RETURNED_M and math.hypot(*self.velocity()[:2]) < 0.3:
                self.returning = False
                self.statustext("RTL: land at destination")
                self._start_land()
            return True
        if self.taking_off:
            if kind == _IDLE:
                if now < self._climb_at:
                    return True
                x, y, _ = self.position()
                self._guide(Kind.POSITION, (x, y, -self._takeoff_alt))
            self._climb_limit()
            if self._takeoff_reached():
                self._takeoff_done()
                return False
            return True
        return False

    def _takeoff_reached(self) -> bool:
        if self.personality.takeoff_alt_accept_m is None:  # ArduPilot: at the altitude, level
            return abs(self.altitude() - self._takeoff_alt) < TAKEOFF_DONE_M and abs(self.velocity()[2]) < 0.3
        # PX4 (mission_block.cpp): above the target minus NAV_MC_ALT_RAD, climbing or not; a
        # radius as large as the take-off altitude is halved
        accept = self.params["takeoff_alt_accept_m"]
        if 0.0 < self._takeoff_alt < accept:
            accept = self._takeoff_alt / 2.0
        return self.altitude() > self._takeoff_alt - accept

    def _touchdown(self) -> None:
        if self.motor_failed:  # measured: ArduCopter stays armed in its mode where it crashed
            self.fleet.guide(self.index, Kind.IDLE)
            for i, text in enumerate(self.personality.crash_texts):
                self.statustext(text, d.MAV_SEVERITY_EMERGENCY if i else d.MAV_SEVERITY_INFO)
            return
        was_armed = self.armed
        self.armed = False  # PX4 and ArduPilot both disarm after landing
        self.fleet.guide(self.index, Kind.IDLE)
        if was_armed:
            self.statustext(self.personality.arm_texts[1])

    def _takeoff_done(self) -> None:
        self.taking_off = False
        p = self.personality
        if p.takeoff_mode is not None and self.mode == p.takeoff_mode:
            self.mode_spec = p.mode(p.hold_mode)
        self._apply_limits()
        if self.behaviour == Behaviour.OFFBOARD and self.setpoint is not None and not self._setpoint_stale():
            self._apply_setpoint()
        self.statustext("Takeoff complete")

    def _setpoint_stale(self) -> bool:
        return self.fleet.now - self.setpoint_time > self.params["offboard_timeout_s"]

    def _enter_failsafe_mode(self, name: str) -> None:
        self.mode_spec = self.personality.mode(name)
        b = self.behaviour
        if b == Behaviour.RETURN:
            self._start_return()
        elif b == Behaviour.LAND:
            self._start_land()
        else:
            self._hold_here()

    def check_setpoint_loss(self, now: float) -> None:
        """Called by the host once this vehicle's setpoint deadline has passed."""
        self._check_setpoint_loss(now)
        self._refresh_deadline()

    def _check_setpoint_loss(self, now: float) -> None:
        if self.setpoint_timed_out or not self._setpoint_stale():
            return
        assert self.setpoint is not None
        if self.personality.failsafe == Failsafe.LEAVE_TO_HOLD:
            p = self.personality
            action = int(self.params["offboard_loss_action"])
            name = p.loss_modes[action] if p.loss_modes else p.hold_mode
            if (self.gps_lost_at is not None and p.no_position_mode is not None
                    and p.mode(name).behaviour in (Behaviour.HOLD, Behaviour.RETURN)):
                name = p.no_position_mode  # measured: PX4 holds its altitude, no position to hold or return by
            self.failsafe = bool(p.loss_modes)
            self.statustext(p.loss_text, d.MAV_SEVERITY_WARNING)
            self._enter_failsafe_mode(name)
            log.info("vehicle %d: offboard setpoints lost at t=%.2f s, %s", self.sysid, now, name)
        elif self.setpoint[0] != Kind.POSITION:
            # ArduPilot keeps GUIDED; a velocity/accel target times out and it brakes.
            self.setpoint_timed_out = True
            self._hold_here()
            self.statustext("Guided timeout: braking", d.MAV_SEVERITY_WARNING)
            log.info("vehicle %d: guided setpoints timed out at t=%.2f s, braking", self.sysid, now)
        else:
            self.setpoint_timed_out = True
