"""The flat-earth conversion, both directions: the numbers the emulator and agent always used."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from plmarl_sitl.model.geodesy import geodetic_to_ned, ned_to_geodetic


def test_same_numbers_as_before_the_move() -> None:
    # Reference values from the emulator's telemetry.geodetic and the agent's frames.home_offset_ned
    # before both became this module: bit for bit.
    assert ned_to_geodetic(47.397742, 8.545594, 488.0, 500.0, 430.0, -12.5) == (47.4022335764206, 8.551300496251278, 500.5)
    assert ned_to_geodetic(-33.9, 151.2, 3.0, -1234.5, 77.25, 0.75) == (-33.91108970218245, 151.20083607022383, 2.25)
    assert geodetic_to_ned(47.397742, 8.545594, 488.0, 47.4021, 8.5512, 500.25) == (485.1303408766754, 422.4273343665947, -12.25)
    assert geodetic_to_ned(-33.9, 151.2, 3.0, -33.91, 151.195, 1.5) == (-1113.1949079325143, -461.9827246444684, 1.5)


@given(st.floats(-80, 80), st.floats(-180, 180), st.floats(-5e3, 5e3), st.floats(-5e3, 5e3), st.floats(-5e3, 5e3))
def test_round_trip(lat0: float, lon0: float, north: float, east: float, down: float) -> None:
    lat, lon, alt = ned_to_geodetic(lat0, lon0, 100.0, north, east, down)
    n, e, d = geodetic_to_ned(lat0, lon0, 100.0, lat, lon, alt)
    assert (n, e, d) == pytest.approx((north, east, down), abs=1e-6)
