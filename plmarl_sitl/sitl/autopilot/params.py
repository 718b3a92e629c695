"""Vehicle parameters: a few real ones, readable and settable over the MAVLink param protocol.

Values are stored in SI units under emulator keys (`offboard_timeout_s`, `max_speed_mps`,
...); the personality decides the wire names, types and units. The speed/acceleration
parameters are the *autopilot's* limits (PX4 MPC_*, ArduPilot WPNAV_*): they can be set
anywhere up to the airframe limits of the vehicle model, which the shared physics enforces
regardless, just as a real controller cannot make an airframe faster than it is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from plmarl_sitl.config import VehicleModel
from plmarl_sitl.deploy.mavlink.codec import decode_param_value, dialect, encode_param_value
from plmarl_sitl.deploy.mavlink.personality import ParamSpec, Personality

_INTEGER_TYPES = {
    dialect.MAV_PARAM_TYPE_UINT8,
    dialect.MAV_PARAM_TYPE_INT8,
    dialect.MAV_PARAM_TYPE_UINT16,
    dialect.MAV_PARAM_TYPE_INT16,
    dialect.MAV_PARAM_TYPE_UINT32,
    dialect.MAV_PARAM_TYPE_INT32,
}


@dataclass(frozen=True)
class Range:
    lo: float
    hi: float


def ranges(model: VehicleModel) -> dict[str, Range]:
    """Allowed SI range of every key; the airframe bounds the autopilot limits."""
    return {
        "offboard_timeout_s": Range(0.0, 60.0),
        "sysid": Range(1, 250),
        "takeoff_alt_m": Range(1.0, model.max_alt_m),
        "max_accel_mps2": Range(0.1, model.max_accel_mps2),
        "max_speed_mps": Range(0.1, model.max_speed_mps),
        "max_climb_mps": Range(0.1, model.max_climb_mps),
        "land_speed_mps": Range(0.1, model.max_climb_mps),
        "takeoff_speed_mps": Range(0.1, model.max_climb_mps),
        "takeoff_alt_accept_m": Range(0.05, 200.0),  # PX4 NAV_MC_ALT_RAD's own bounds
        "offboard_loss_action": Range(0, 5),
        "accel_drag_per_s": Range(0.0, 10.0),  # PX4 COM_OBL_RC_ACT: 0-3 RTL (no RC), 4 land, 5 hold
        "gps_satellites": Range(0, 50),  # PX4 SIH SIM_GPS_USED: below GPS_FIX_MIN_SATELLITES, no fix
    }


def defaults(model: VehicleModel, personality: Personality, sysid: int) -> dict[str, float]:
    return {
        "offboard_timeout_s": personality.offboard_timeout_s,
        "sysid": float(sysid),
        "takeoff_alt_m": model.takeoff_alt_m,
        "max_accel_mps2": model.max_accel_mps2,
        "max_speed_mps": model.max_speed_mps,
        "max_climb_mps": model.max_climb_mps,
        "land_speed_mps": min(personality.land_speed_mps, model.max_climb_mps),
        "takeoff_speed_mps": min(personality.takeoff_speed_mps or model.max_climb_mps, model.max_climb_mps),
        "takeoff_alt_accept_m": personality.takeoff_alt_accept_m or 0.0,  # read only where the personality has it
        "offboard_loss_action": 0.0,
        "accel_drag_per_s": personality.accel_drag_per_s,
        "gps_satellites": 10.0,  # PX4 SIH's default
    }


class ParamStore:
    """The parameter table of one vehicle."""

    def __init__(self, model: VehicleModel, personality: Personality, sysid: int) -> None:
        self.personality = personality
        self.specs: tuple[ParamSpec, ...] = personality.params
        self._index = {s.name: i for i, s in enumerate(self.specs)}
        self._ranges = ranges(model)
        self.values: dict[str, float] = defaults(model, personality, sysid)

    def __getitem__(self, key: str) -> float:
        return self.values[key]

    def index_of(self, name: str) -> int | None:
        return self._index.get(name)

    def wire(self, index: int) -> tuple[str, float, int]:
        """(param_id, encoded value, type) for PARAM_VALUE."""
        s = self.specs[index]
        v = self.values[s.key] * s.scale
        if s.param_type in _INTEGER_TYPES:
            v = float(round(v))
        return s.name, encode_param_value(v, s.param_type, self.personality.param_bytewise), s.param_type

    def set_from_wire(self, name: str, wire_value: float) -> str | None:
        """Apply a PARAM_SET. Returns None on success or the reason it was refused."""
        i = self._index.get(name)
        if i is None:
            return "unknown parameter"
        s = self.specs[i]
        raw = decode_param_value(wire_value, s.param_type, self.personality.param_bytewise)
        if not math.isfinite(raw):
            return "not a finite number"
        if s.param_type in _INTEGER_TYPES:
            raw = float(round(raw))
        si = raw / s.scale
        r = self._ranges[s.key]
        if not r.lo <= si <= r.hi:
            return f"out of range [{r.lo:g}, {r.hi:g}]"
        self.values[s.key] = si
        return None
