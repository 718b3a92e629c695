"""The mission frame and latitude/longitude: one flat-earth conversion, both directions.

The mission frame is local NED in metres (x north, y east, z down) with geodetic origin
`mission.origin`. The emulator reports GLOBAL_POSITION_INT and HOME_POSITION with
`to_geodetic`; an agent places its vehicle's home in the mission frame with
`to_ned_offset`. Flat earth on the WGS-84 equatorial radius: good to centimetres over a
few km, which is all a mission area spans.
"""

from __future__ import annotations

import math

EARTH_RADIUS_M = 6_378_137.0


def to_geodetic(lat0: float, lon0: float, alt0: float, north: float, east: float, up: float) -> tuple[float, float, float]:
    """(lat, lon, alt) of the point `north`, `east`, `up` metres from (lat0, lon0, alt0)."""
    lat = lat0 + math.degrees(north / EARTH_RADIUS_M)
    lon = lon0 + math.degrees(east / (EARTH_RADIUS_M * math.cos(math.radians(lat0))))
    return lat, lon, alt0 + up


def to_ned_offset(lat0: float, lon0: float, alt0: float, lat: float, lon: float, alt: float) -> tuple[float, float, float]:
    """(north, east, down) metres of (lat, lon, alt) from (lat0, lon0, alt0): the inverse."""
    north = math.radians(lat - lat0) * EARTH_RADIUS_M
    east = math.radians(lon - lon0) * EARTH_RADIUS_M * math.cos(math.radians(lat0))
    return north, east, -(alt - alt0)
