"""Mission frame <-> geodetic: where the vehicle's home (local NED origin) is in the mission.

The mission frame is metres from the area's SW corner, x north, y east, z down, with
geodetic origin `mission.origin`; the inverse of the flat-earth offset the emulator (and
the world) use. Good to centimetres over a few km.
"""

from __future__ import annotations

import math

from plmarl_sitl.mission import Origin

EARTH_RADIUS_M = 6_378_137.0


def home_offset_ned(origin: Origin, lat_deg: float, lon_deg: float, alt_m: float) -> tuple[float, float, float]:
    north = math.radians(lat_deg - origin.lat_deg) * EARTH_RADIUS_M
    east = math.radians(lon_deg - origin.lon_deg) * EARTH_RADIUS_M * math.cos(math.radians(origin.lat_deg))
    return north, east, -(alt_m - origin.alt_m)
