"""The agent's vehicle session: everything it says to its autopilot over MAVLink.

Start-up: heartbeat (-> personality), position and home valid, setpoints streaming, mode
(PX4 OFFBOARD after the stream is up, ArduPilot GUIDED), arm and take off (or attach to
an airborne vehicle with `takeoff=False`). Flying: every telemetry message goes to the
agent (`on_telemetry`, which sends the setpoint), a wall-clock watchdog keeps the stream
up if telemetry stalls, a GCS heartbeat goes out at 1 Hz, and the offboard mode is asked
back after a setpoint-loss failsafe. Stop: the personality's stop mode (hold or brake).
Every mode name comes from the personality.
"""

from __future__ import annotations

import asyncio
import contextlib
import gc
import logging
import math
import time
from collections.abc import Callable
from typing import Any, Protocol

import torch

from plmarl_sitl.deploy.agent.clock import MissionClock
from plmarl_sitl.deploy.agent.config import AgentConfig
from plmarl_sitl.deploy.agent.decision import Decision
from plmarl_sitl.deploy.agent.stats import LoopStats, rss_mb
from plmarl_sitl.deploy.mavlink.personality import Personality
from plmarl_sitl.errors import CommandRejected, UserError, VehicleTimeout
from plmarl_sitl.model.geodesy import geodetic_to_ned

log = logging.getLogger("plmarl.agent")

# LOCAL_POSITION_NED rate we ask for (vehicle time); one setpoint goes out per message, so
# this is also the setpoint rate (>= 10 Hz; PX4 needs > 2 Hz). 20 Hz doubles the load on a
# SITL world of 20 vehicles at speedup 10 for no gain in a policy acting every 3 s.
TELEMETRY_HZ = 10.0
WATCHDOG_S = 0.1  # wall: re-send the setpoint if telemetry stalls (>= 10 Hz)
HOME_POSITION_ID = 242  # MAVLINK_MSG_ID_HOME_POSITION
UNUSED_STREAMS = {"ATTITUDE": 0.0, "POSITION_TARGET_LOCAL_NED": 0.0, "GLOBAL_POSITION_INT": 1.0}
REENGAGE_EVERY_S = 2.0  # wall: how often to ask for the offboard mode back after a failsafe


class Link(Protocol):
    """The MAVLink link to the autopilot, as the agent uses it (`mavlink.client.VehicleLink`)."""

    personality: Personality | None  # from the autopilot's heartbeat, once open
    latest: dict[str, Any]  # the latest message of each type

    @property
    def sysid(self) -> int: ...
    async def open(self, timeout: float = ...) -> None: ...
    def close(self) -> None: ...
    async def recv(self, mtype: str, timeout: float = ...) -> Any: ...
    async def request(self, mtype: str, msgid: int, timeout: float = ...) -> Any: ...
    async def set_message_interval(self, message: str | int, hz: float) -> None: ...
    async def set_mode(self, name: str) -> None: ...
    async def arm(self, force: bool = ...) -> None: ...
    async def takeoff(self, alt_rel_m: float | None = ..., home_amsl_m: float | None = ...) -> None: ...
    def send_accel_ned(self, north: float, east: float, down: float) -> None: ...
    def send_heartbeat(self) -> None: ...


class VehicleSession:
    def __init__(self, link: Link, cfg: AgentConfig, clock: MissionClock, decision: Decision, stats: LoopStats,
                 t_proc0: float, on_telemetry: Callable[[Any], None]) -> None:
        self.link, self.cfg, self.clock, self.decision, self.stats = link, cfg, clock, decision, stats
        self.t_proc0 = t_proc0  # unix time the process started (start-up is counted from it)
        self.on_telemetry = on_telemetry  # each LOCAL_POSITION_NED goes here
        self.vm = cfg.mission.vehicle_model()
        self.started = False  # start() has begun using the link
        self.personality: Personality | None = None  # once the autopilot is found
        self.home = torch.zeros(3)  # the vehicle's local origin in the mission frame
        self.flying = False  # streaming setpoints
        self.last_send_wall = 0.0
        self.reengaged = 0
        self._last_reengage = 0.0
        self._reengage_task: asyncio.Task | None = None

    def mission_state(self, m: Any) -> torch.Tensor:
        """[p, v] in the mission frame from a LOCAL_POSITION_NED."""
        local = torch.tensor([m.x, m.y, m.z, m.vx, m.vy, m.vz], dtype=torch.float32)
        return torch.cat([local[:3] + self.home, local[3:]])

    # ------------------------------------------------------------------ setpoints
    def send_setpoint(self) -> None:
        self.link.send_accel_ned(*self.decision.command())
        self.last_send_wall = time.perf_counter()

    async def watchdog(self) -> None:
        """>= 10 Hz wall even if telemetry stalls (PX4 leaves OFFBOARD after 1 s without)."""
        while True:
            await asyncio.sleep(WATCHDOG_S / 2)
            if self.flying and time.perf_counter() - self.last_send_wall >= WATCHDOG_S:
                self.send_setpoint()

    async def gcs_heartbeat(self) -> None:
        """A companion computer announces itself at 1 Hz (autopilots track their peers)."""
        while True:
            if self.started:
                self.link.send_heartbeat()
            await asyncio.sleep(1.0)

    # ------------------------------------------------------------------ startup
    async def _telemetry(self) -> None:
        self.on_telemetry(await self.link.recv("LOCAL_POSITION_NED", 5.0))

    async def _wait_until(self, what: str, cond: Callable[[], bool], timeout_s: float) -> None:
        """Wait on telemetry until cond() holds; timeout in VEHICLE seconds (speedup-safe)."""
        start = self.clock.boot_s
        while not cond():
            await self._telemetry()
            if self.clock.boot_s - start > timeout_s:
                raise VehicleTimeout(self.link.sysid, what, timeout_s)

    def _alt(self) -> float:
        return -float(self.decision.ego[2])

    async def _set_mode(self, name: str) -> None:
        for attempt in range(5):
            try:
                await self.link.set_mode(name)
                return
            except CommandRejected as exc:
                if exc.result_name != "MAV_RESULT_TEMPORARILY_REJECTED" or attempt == 4:
                    raise
                await asyncio.sleep(0.2)

    async def start(self) -> None:
        """Find the autopilot, then take off (or attach) and switch to the offboard mode."""
        cfg, link = self.cfg, self.link
        self.started = True
        try:
            await link.open(timeout=cfg.connect_timeout_s)
        except VehicleTimeout as exc:
            raise UserError(f"no autopilot heartbeat on {cfg.connect_url} within {cfg.connect_timeout_s:g} s") from exc
        assert link.personality is not None
        p = link.personality
        if cfg.autopilot != "auto" and cfg.autopilot != p.name:
            raise UserError(f"--autopilot {cfg.autopilot}, but the vehicle's heartbeat says {p.name}")
        self.personality = p
        log.info("vehicle sysid %d on %s: %s personality (heartbeat at %.2f s)", link.sysid, cfg.connect_url, p.name,
                 time.time() - self.t_proc0)
        await link.set_message_interval("LOCAL_POSITION_NED", TELEMETRY_HZ)
        home = await link.request("HOME_POSITION", HOME_POSITION_ID, timeout=3.0)
        o = cfg.mission.origin
        offset = geodetic_to_ned(o.lat_deg, o.lon_deg, o.alt_m, home.latitude / 1e7, home.longitude / 1e7, home.altitude / 1000.0)
        self.home = torch.tensor(offset, dtype=torch.float32)
        await self._telemetry()
        # Start-up ends here: policy loaded, autopilot found, position and home valid.
        # What follows (arming, climbing) is the vehicle's time, not the agent's.
        self.stats.startup_s = time.time() - self.t_proc0
        log.info("ready after %.2f s (process start -> telemetry and home valid), RSS %.0f MB", self.stats.startup_s, rss_mb())
        # Streams the agent does not use cost the autopilot link (and, in SITL, the
        # world's CPU) for nothing; our MAVLink instance is ours alone, a GCS has its own.
        for name, hz in UNUSED_STREAMS.items():
            with contextlib.suppress(CommandRejected, VehicleTimeout):
                await link.set_message_interval(name, hz)
        # Everything alive now (torch, the policy, the loop) lives for the whole flight:
        # freezing it keeps full GC passes from walking ~10^5 objects mid-decision. Done
        # here, on the ground, because the collection itself takes a while.
        gc.collect()
        gc.freeze()
        hb = link.latest.get("HEARTBEAT")
        armed = bool(hb and hb.base_mode & 128)
        alt_tgt = min(max(self.vm.takeoff_alt_m, self.vm.min_alt_m), self.vm.max_alt_m)
        if cfg.takeoff and not armed:
            if p.takeoff_needs_offboard_mode:  # ArduPilot: GUIDED, arm, NAV_TAKEOFF
                await self._set_mode(p.offboard_mode)
                await link.arm()
                await link.takeoff(alt_tgt)
            else:  # PX4: arm, AUTO.TAKEOFF, then OFFBOARD once the stream is up
                await link.arm()
                await link.takeoff(alt_tgt, home_amsl_m=home.altitude / 1000.0)
            await self._wait_until(
                "takeoff", lambda: self._alt() >= alt_tgt - 0.5 and abs(float(self.decision.ego[5])) < 0.3, cfg.takeoff_timeout_s
            )
        elif not armed:
            raise UserError("--no-takeoff: the vehicle is not armed (attach only to a flying vehicle)")
        # PX4 refuses OFFBOARD until setpoints stream: stream first (hold here), then switch.
        self.decision.hold_target = self.decision.ego[:3].clone()
        self.flying = True
        for _ in range(5):
            await self._telemetry()
        await self._set_mode(p.offboard_mode)
        log.info("in %s at %.1f m, %.2f s after process start", p.offboard_mode, self._alt(), time.time() - self.t_proc0)

    async def common_epoch(self) -> float:
        """t0 on this vehicle's boot clock that every agent of the swarm agrees on, with no
        world to announce it: the last UTC midnight of the autopilot's (GPS-disciplined)
        SYSTEM_TIME. Signalling instants are then multiples of T_up since midnight on every
        vehicle. Without a unix time (no GPS yet) fall back to boot time 0, which agrees
        only between vehicles that booted together (one SITL host)."""
        try:
            st = await self.link.recv("SYSTEM_TIME", 5.0)
        except VehicleTimeout:
            st = None
        if st is None or st.time_unix_usec == 0:
            log.warning("no SYSTEM_TIME unix time from the autopilot: signalling instants follow its boot clock")
            return 0.0
        unix_s = st.time_unix_usec / 1e6
        offset = unix_s - st.time_boot_ms / 1e3  # unix time at boot
        return math.floor(unix_s / 86400.0) * 86400.0 - offset

    # ------------------------------------------------------------------ flying
    async def fly(self, stop: asyncio.Event) -> None:
        """Serve telemetry until `stop` is set (raises VehicleTimeout if the vehicle goes silent)."""
        while not stop.is_set():
            await self._telemetry()
            self._check_mode()

    def _check_mode(self) -> None:
        """If the autopilot left the offboard mode on its own (a setpoint-loss failsafe
        after a stall of this process), ask for it back once the stream is flowing again,
        at most every REENGAGE_EVERY_S. A mode a pilot chose is left alone: only the
        personality's failsafe hold mode triggers this."""
        hb = self.link.latest.get("HEARTBEAT")
        if hb is None or hb.get_srcComponent() != 1:
            return
        p = self.personality
        assert p is not None
        mode = p.mode_by_custom(hb.custom_mode)
        if mode is None or mode.name != p.hold_mode or not hb.base_mode & 128:
            return
        now = time.perf_counter()
        if now - self._last_reengage < REENGAGE_EVERY_S or self._reengage_task is not None and not self._reengage_task.done():
            return
        self._last_reengage = now
        self.reengaged += 1
        log.warning("vehicle fell back to %s (setpoint-loss failsafe); re-engaging %s", mode.name, p.offboard_mode)
        self._reengage_task = asyncio.ensure_future(self._reengage(p.offboard_mode))

    async def _reengage(self, mode: str) -> None:
        try:
            async with asyncio.timeout(3.0):
                await self._set_mode(mode)
        except (TimeoutError, VehicleTimeout, CommandRejected) as exc:
            log.error("could not re-engage %s: %s", mode, exc)

    async def hold(self) -> None:
        """Stop: hand a flying vehicle to the personality's stop mode (PX4 AUTO.LOITER,
        ArduPilot BRAKE)."""
        if self.personality is None or not self.flying:
            return
        mode = self.personality.stop_mode
        try:
            async with asyncio.timeout(3.0):
                await self._set_mode(mode)
            log.warning("stopped: vehicle in %s", mode)
        except (TimeoutError, VehicleTimeout, CommandRejected) as exc:
            log.error("stopped, but could not command %s: %s (the autopilot's own failsafe takes over)", mode, exc)

    def close(self) -> None:
        if self.started:
            self.link.close()
