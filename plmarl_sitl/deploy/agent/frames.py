"""Mission frame <-> geodetic: where the vehicle's home (local NED origin) is in the mission.

The mission frame is metres from the area's SW corner, x north, y east, z down, with
geodetic origin `mission.origin`; the inverse of the flat-earth offset the emulator (and
the world) use (`plmarl_sitl.model.geodesy`). Good to centimetres over a few km.
"""

from __future__ import annotations

from plmarl_sitl.mission import Origin
from plmarl_sitl.model.geodesy import geodetic_to_ned


def home_offset_ned(origin: Origin, lat_deg: float, lon_deg: float, alt_m: float) -> tuple[float, float, float]:
    return geodetic_to_ned(origin.lat_deg, origin.lon_deg, origin.alt_m, lat_deg, lon_deg, alt_m)
