"""When the SITL world's mission time starts, and the mission clock its parts share.

Mission time starts when every vehicle is flying under its agent (armed, in the offboard
mode, at takeoff altitude; external vehicles: and no longer climbing), or at the start
timeout with whoever is ready. The world then announces `t0` (a whole second, a margin
ahead, so the announcement reaches every agent before it) on the retained `start` topic,
and, for vehicles with clocks of their own, that instant on each one's clock
(`t0_boot_s_by_uav`). Agents count mission seconds from t0 on their own vehicle clock, so
the twin's t = 0 (the launch line at takeoff altitude) is the same instant on both sides.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

from plmarl_sitl.sitl.vehicles import WorldVehicles

log = logging.getLogger("plmarl.world")

WAIT_LOG_EVERY_S = 30  # vehicle s: how often the world says what it waits for before the start


@dataclass
class MissionTime:
    """The mission clock as the world's parts read it; only the world writes it."""

    tup_s: int  # the signalling interval in force (a tup_change event changes it)
    t0: float | None = None  # boot second of mission t = 0 (external vehicles: on the reference clock)
    t0_by_uav: list[float] | None = None  # ... on each vehicle's own clock, if they differ
    k: int | None = None  # the last whole mission second processed
    wall0: float | None = None  # perf_counter at mission second 0


class StartGate:
    """Whether the mission can start, and its t0 when it does."""

    def __init__(self, vehicles: WorldVehicles, takeoff_alt: float, timeout_s: float, margin_s: float) -> None:
        self.vehicles = vehicles
        self.takeoff_alt = takeoff_alt  # the twin's start altitude
        self.timeout_s = timeout_s  # sim s: start anyway with whoever is ready
        self.margin_s = margin_s  # sim s: t0 is at least this far ahead of the announcement

    def not_ready(self) -> list[str]:
        """Why the mission cannot start yet: one entry per vehicle not flying under its agent."""
        return self.vehicles.not_ready(self.takeoff_alt)

    def t0_at(self, second: float, now: float) -> tuple[float, list[str]] | None:
        """At boot second `second` (vehicle clock `now`): the mission's t0 and the vehicles
        left behind by the start timeout, if it starts now; else None."""
        emulated = self.vehicles.owns_clock
        if int(second) % WAIT_LOG_EVERY_S == 0:
            log.info("waiting for every vehicle to fly under its agent (armed, %s, at %.0f m%s): not yet %s",
                     "in the offboard mode" if emulated else "in its offboard mode: PX4 OFFBOARD, ArduPilot GUIDED",
                     self.takeoff_alt, "" if emulated else ", climb over", ", ".join(self.not_ready()) or "none")
        if self.not_ready() and now < self.timeout_s:
            return None
        left_behind = self.not_ready()
        if left_behind:
            log.warning("start timeout: starting the mission with the vehicles that are ready")
        return float(math.ceil(now + self.margin_s)), left_behind
