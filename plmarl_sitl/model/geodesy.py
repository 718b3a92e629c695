"""Flat-earth conversion between geodetic coordinates and local NED offsets.

Both directions use one sphere of the WGS-84 equatorial radius; over a mission area of a
few km the error is centimetres. The emulator reports its vehicles' positions with
`ned_to_geodetic`, the agent finds its home in the mission frame with `geodetic_to_ned`,
so the two agree exactly.
"""

from __future__ import annotations

import math

EARTH_RADIUS_M = 6_378_137.0


def ned_to_geodetic(
    lat0_deg: float, lon0_deg: float, alt0_m: float, north_m: float, east_m: float, down_m: float
) -> tuple[float, float, float]:
    """(lat, lon, alt) of the point `north, east, down` metres from (lat0, lon0, alt0)."""
    lat = lat0_deg + math.degrees(north_m / EARTH_RADIUS_M)
    lon = lon0_deg + math.degrees(east_m / (EARTH_RADIUS_M * math.cos(math.radians(lat0_deg))))
    return lat, lon, alt0_m - down_m


def geodetic_to_ned(
    lat0_deg: float, lon0_deg: float, alt0_m: float, lat_deg: float, lon_deg: float, alt_m: float
) -> tuple[float, float, float]:
    """(north, east, down) metres of (lat, lon, alt) from (lat0, lon0, alt0)."""
    north = math.radians(lat_deg - lat0_deg) * EARTH_RADIUS_M
    east = math.radians(lon_deg - lon0_deg) * EARTH_RADIUS_M * math.cos(math.radians(lat0_deg))
    return north, east, -(alt_m - alt0_m)


def local_frame_origin(
    lat0_deg: float, lon0_deg: float, alt0_m: float, home: tuple[float, float, float], home_local: tuple[float, float, float]
) -> tuple[float, float, float]:
    """Where a vehicle's local NED frame has its origin, in NED metres from (lat0, lon0, alt0),
    from its home known both geodetically (`home`: lat, lon, alt) and in the local frame
    (`home_local`: x, y, z of HOME_POSITION; ArduPilot's EKF origin need not be the home).
    A position p in the vehicle's local frame is then at origin + p."""
    h = geodetic_to_ned(lat0_deg, lon0_deg, alt0_m, *home)
    return h[0] - home_local[0], h[1] - home_local[1], h[2] - home_local[2]
