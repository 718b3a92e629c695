"""One view of a vehicle from its MAVLink link, for every program that follows one.

The agent's session (`deploy.agent.session`) and the SITL world's link to an external
autopilot (`sitl.external`) read the same things from a vehicle, so they read them here
(MAVSDK keeps them in its telemetry and info plugins the same way):

* its state from the autopilot's HEARTBEAT: the armed flag and the mode named by the
  personality. Only the autopilot component of the vehicle's system counts: a GCS or a
  companion on the same system id (a router forwards their heartbeats) says nothing about
  the vehicle;
* where its local NED frame lies in the mission frame, from HOME_POSITION (`place_home`);
* the optional requests (REQUEST_MESSAGE, SET_MESSAGE_INTERVAL) an autopilot may refuse or
  leave unanswered because it streams the message anyway: False then, not an error; a lost
  link still ends the caller's wait (LinkLost).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

from plmarl_sitl.deploy.mavlink.codec import dialect
from plmarl_sitl.deploy.mavlink.personality import Personality
from plmarl_sitl.errors import CommandRejected, VehicleTimeout
from plmarl_sitl.model.geodesy import local_frame_origin

log = logging.getLogger("plmarl.mavlink")

AUTOPILOT_COMPONENT = dialect.MAV_COMP_ID_AUTOPILOT1
ARMED = dialect.MAV_MODE_FLAG_SAFETY_ARMED  # of HEARTBEAT.base_mode
HOME_POSITION_ID = dialect.MAVLINK_MSG_ID_HOME_POSITION
LOCAL_POSITION_NED_ID = dialect.MAVLINK_MSG_ID_LOCAL_POSITION_NED
SYSTEM_TIME_ID = dialect.MAVLINK_MSG_ID_SYSTEM_TIME


class ViewedLink(Protocol):
    """What the view needs of a link (`mavlink.client.VehicleLink`)."""

    personality: Personality | None
    latest: dict[str, Any]

    @property
    def sysid(self) -> int: ...
    async def recv(self, mtype: str, timeout: float = ..., pred: Callable[[Any], bool] | None = ...) -> Any: ...
    async def request_message(self, msgid: int, timeout: float | None = ...) -> None: ...
    async def set_message_interval(self, message: str | int, hz: float) -> None: ...


@dataclass(frozen=True)
class VehicleState:
    """What an autopilot HEARTBEAT says: armed, and the mode (its personality's name, or
    the custom_mode number if the personality does not name it)."""

    armed: bool
    mode: str
    custom_mode: int


def decode_heartbeat(hb: Any, personality: Personality | None) -> VehicleState:
    name = personality.mode_name(hb.custom_mode) if personality is not None else None
    return VehicleState(armed=bool(hb.base_mode & ARMED), mode=name if name is not None else str(hb.custom_mode),
                        custom_mode=int(hb.custom_mode))


@dataclass(frozen=True)
class HomePlacement:
    """A vehicle's home, geodetically (lat, lon in degrees, alt in m AMSL) and in its local
    NED frame, and so where that frame's origin lies in the mission frame (NED m from the
    mission origin): a local position p is at origin + p."""

    lat_deg: float
    lon_deg: float
    alt_m: float
    local: tuple[float, float, float]
    origin: tuple[float, float, float]


def place_home(origin_lat_deg: float, origin_lon_deg: float, origin_alt_m: float, home: Any) -> HomePlacement:
    """A HOME_POSITION placed in the mission frame whose origin is given. Its x, y, z are
    the home in the local frame (ArduPilot's EKF origin need not be the home); an
    autopilot that reports none (NaN) has its local frame start at home."""
    lat, lon, alt = home.latitude / 1e7, home.longitude / 1e7, home.altitude / 1000.0
    local = (float(home.x), float(home.y), float(home.z))
    if not all(math.isfinite(v) for v in local):
        local = (0.0, 0.0, 0.0)
    return HomePlacement(lat, lon, alt, local, local_frame_origin(origin_lat_deg, origin_lon_deg, origin_alt_m,
                                                                  (lat, lon, alt), local))


class VehicleView:
    """The vehicle behind one link, as its autopilot reports it."""

    def __init__(self, link: ViewedLink) -> None:
        self.link = link
        self._latest: tuple[Any, VehicleState | None] = (None, None)  # (heartbeat, its state): read per sample

    def from_autopilot(self, m: Any) -> bool:
        """Whether `m` comes from the vehicle's autopilot (not a GCS's or companion's)."""
        return m.get_srcComponent() == AUTOPILOT_COMPONENT and m.get_srcSystem() == self.link.sysid

    def state(self, hb: Any) -> VehicleState:
        """A HEARTBEAT of the autopilot (see `from_autopilot`), decoded."""
        return decode_heartbeat(hb, self.link.personality)

    def latest_state(self) -> VehicleState | None:
        """The latest heartbeat's state, if the latest heartbeat came from the autopilot."""
        hb = self.link.latest.get("HEARTBEAT")
        if hb is None:
            return None
        seen, state = self._latest
        if hb is not seen:  # a new heartbeat (1 Hz): decode it once, not at every sample
            state = self.state(hb) if self.from_autopilot(hb) else None
            self._latest = (hb, state)
        return state

    async def next_state(self, timeout: float = 3.0) -> VehicleState:
        """The state of the autopilot's next heartbeat (VehicleTimeout, LinkLost)."""
        return self.state(await self.link.recv("HEARTBEAT", timeout, self.from_autopilot))

    async def request(self, msgid: int) -> bool:
        """REQUEST_MESSAGE, for an answer that comes through a subscription: False if the
        autopilot refused it or did not acknowledge it (one that streams the message needs
        no asking); LinkLost is raised."""
        try:
            await self.link.request_message(msgid)
            return True
        except (CommandRejected, VehicleTimeout) as exc:
            log.debug("vehicle sysid %d: REQUEST_MESSAGE %d: %s", self.link.sysid, msgid, exc)
            return False

    async def stream(self, message: str | int, hz: float) -> bool:
        """SET_MESSAGE_INTERVAL (0 Hz: stop the stream): False if refused or unacknowledged,
        to be asked again or done without; LinkLost is raised."""
        try:
            await self.link.set_message_interval(message, hz)
            return True
        except (CommandRejected, VehicleTimeout) as exc:
            log.debug("vehicle sysid %d: SET_MESSAGE_INTERVAL %s at %g Hz: %s", self.link.sysid, message, hz, exc)
            return False
