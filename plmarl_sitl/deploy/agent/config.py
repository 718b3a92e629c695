"""What one agent is started with (the `plmarl agent` flags, parsed)."""

from __future__ import annotations

import random
from dataclasses import dataclass, field
from pathlib import Path

from plmarl_sitl.deploy.mqtt.auth import SwarmKey
from plmarl_sitl.deploy.mqtt.schema import INSTANT_WAIT_WALL_S
from plmarl_sitl.errors import UserError
from plmarl_sitl.mission import Mission

MAX_AIRFRAME_DRAG_PER_S = 10.0


@dataclass(frozen=True)
class StartupBounds:
    """How long start-up waits for each step, in wall seconds from the step's start.

    A real ArduCopter SITL at 1x sets its home ~19 s and streams LOCAL_POSITION_NED ~40 s
    after the link comes up (its EKF needs GPS first); a real vehicle can take longer
    for a GPS fix. A sped-up SITL or the emulator gets there sooner, so wall bounds sized
    for 1x hold at any speedup."""

    heartbeat_s: float = 30.0  # an autopilot heartbeat on the link
    home_s: float = 120.0  # HOME_POSITION (home set: GPS fix and EKF origin)
    position_s: float = 120.0  # the first LOCAL_POSITION_NED (the EKF uses GPS)
    arm_s: float = 60.0  # the offboard mode and arming accepted (pre-arm checks pass)

    def __post_init__(self) -> None:
        for name in ("heartbeat_s", "home_s", "position_s", "arm_s"):
            if not getattr(self, name) > 0:
                raise UserError(f"start-up bound {name} must be > 0 s")


@dataclass(frozen=True)
class AgentConfig:
    uav_id: int
    connect_url: str  # the autopilot's URL, for messages (whoever starts the agent builds the link)
    mission: Mission
    autopilot: str = "auto"  # auto or a personality name
    tup_s: int | None = None  # None: mission.signalling.tup_s
    swarm: str = "sitl"
    bus_mode: str = "sitl"  # sitl: the world relays tx -> rx/<id>; direct: subscribe tx/+
    takeoff: bool = True
    wait_start: bool = True  # wait for the world's start announcement (else start now)
    settle_min_s: float = 0.1  # vehicle s: an instant is never closed earlier than this
    settle_wall_s: float = INSTANT_WAIT_WALL_S  # wall s: ... and at most this late (x the observed speedup, >= INSTANT_WAIT_MIN_S)
    bounds: StartupBounds = StartupBounds()
    takeoff_timeout_s: float = 120.0  # vehicle seconds
    trace_path: Path | None = None
    stats_path: Path | None = None
    # The swarm key: every message sent is signed and every message received must
    # authenticate (docs/SIGNALLING.md, schema version 2); None: unsigned (--no-auth).
    swarm_key: SwarmKey | None = None
    # Signalling session: receivers tell a restarted agent's messages from its predecessor's
    # by it (also part of the MQTT client id).
    session_id: int = field(default_factory=lambda: random.getrandbits(16))
    # Lockstep SITL (`deploy.agent.lockstep`): stamp each setpoint with the telemetry it
    # answers, answer a boot second's telemetry only after the world's tick for it.
    lockstep: bool = False
    # The airframe's linear drag per unit mass (1/s) the agent adds back to each command's
    # horizontal part (decision.Decision.command says why not the vertical):
    # PX4 flies an acceleration-only setpoint as a feed-forward with no velocity loop around
    # it (PositionControl), so drag turns a commanded a into a speed of a / k instead of the
    # policy's acceleration (PX4 SIH: SIH_KDV / SIH_MASS = 1 /s). 0: the vehicle flies the
    # command as a net acceleration (the emulator in a SITL world, ArduCopter's velocity loop).
    airframe_drag_per_s: float = 0.0

    def __post_init__(self) -> None:
        if not 0.0 <= self.airframe_drag_per_s <= MAX_AIRFRAME_DRAG_PER_S:
            raise UserError(f"--airframe-drag {self.airframe_drag_per_s:g}: must be 0..{MAX_AIRFRAME_DRAG_PER_S:g} /s")
        n = self.mission.n_uavs
        if not 0 <= self.uav_id < n:
            raise UserError(f"--id {self.uav_id}: the mission has {n} UAVs (ids 0..{n - 1})")
