"""Personalities: found by name or by a heartbeat's autopilot field, never guessed."""

from __future__ import annotations

import pytest

from plmarl_sitl.deploy.mavlink.codec import dialect as d
from plmarl_sitl.deploy.mavlink.personality import ARDUPILOT, PX4, personality, personality_for_autopilot
from plmarl_sitl.errors import UserError
from plmarl_sitl.sitl.autopilot import AutopilotHost


def test_known_autopilots_by_name_and_heartbeat() -> None:
    assert personality("px4") is PX4 and personality("ardupilot") is ARDUPILOT
    assert personality_for_autopilot(d.MAV_AUTOPILOT_PX4) is PX4
    assert personality_for_autopilot(d.MAV_AUTOPILOT_ARDUPILOTMEGA) is ARDUPILOT


def test_an_unknown_autopilot_is_an_error_listing_the_known_ones() -> None:
    with pytest.raises(UserError, match=r"unknown autopilot 'inav' \(known: px4, ardupilot\)"):
        personality("inav")
    with pytest.raises(UserError, match=r"unknown autopilot 'PX4'"):
        AutopilotHost(1, personality_name="PX4")
    # A heartbeat from another firmware used to be taken for ArduPilot.
    with pytest.raises(UserError, match="MAV_AUTOPILOT_GENERIC; known: px4 .*MAV_AUTOPILOT_PX4.*, ardupilot"):
        personality_for_autopilot(d.MAV_AUTOPILOT_GENERIC)
