"""The agent's vehicle session: everything it says to its autopilot over MAVLink.

Start-up, each wait bounded (`config.StartupBounds`) and announced in an INFO line: an
autopilot heartbeat (-> personality), the home position (a real EKF sets it ~20 s after
boot), which must lie near the mission area, the local position stream (a real EKF
streams it once it uses GPS, ~40 s after boot), then the take-off decision from the
ARMED flag and the height above home: a vehicle on the ground gets the offboard mode
(ArduPilot GUIDED), is armed once its pre-arm checks pass, and takes off; an armed
vehicle in the air is attached to as it flies. Flying: every telemetry message goes to
the agent (`on_telemetry`, which sends the setpoint), a wall-clock watchdog keeps the
stream up if telemetry stalls, a GCS heartbeat goes out at 1 Hz, and the offboard mode is
asked back after a setpoint-loss failsafe. Stop: the personality's stop mode (hold or
brake). Every mode name comes from the personality.
"""

from __future__ import annotations

import asyncio
import contextlib
import gc
import logging
import math
import time
from collections.abc import Awaitable, Callable
from typing import Any, Protocol

import numpy as np
import torch

from plmarl_sitl.deploy.agent.clock import MissionClock
from plmarl_sitl.deploy.agent.config import AgentConfig
from plmarl_sitl.deploy.agent.decision import Decision
from plmarl_sitl.deploy.agent.stats import LoopStats, rss_mb
from plmarl_sitl.deploy.mavlink.personality import Personality
from plmarl_sitl.deploy.mavlink.vehicle_view import HOME_POSITION_ID, SYSTEM_TIME_ID, VehicleView, place_home
from plmarl_sitl.errors import CommandRejected, UserError, VehicleLost, VehicleTimeout, VehicleUnreachable
from plmarl_sitl.mission import Mission
from plmarl_sitl.model.geodesy import EARTH_RADIUS_M, geodetic_to_ned

log = logging.getLogger("plmarl.agent")

# LOCAL_POSITION_NED rate we ask for (vehicle time); one setpoint goes out per message, so
# this is also the setpoint rate (>= 10 Hz; PX4 needs > 2 Hz). 20 Hz doubles the load on a
# SITL world of 20 vehicles at speedup 10 for no gain in a policy acting every 3 s.
TELEMETRY_HZ = 10.0
# Lockstep SITL: the world moves vehicle time only once every agent has answered a sample, so each
# sample is a round trip through every agent (issue 25). The command changes only at a second's
# first sample (at whole vehicle seconds on lockstep's common grid, at either rate), so 5 Hz flies the
# same seconds with half the round trips.
LOCKSTEP_TELEMETRY_HZ = 5.0
# LOCAL_POSITION_NED rate during the climb (vehicle time): the agent only watches the height
# and, on PX4, keeps the offboard signal alive (COM_OF_LOSS_T 1 s; > 2 Hz before the switch,
# which comes after TELEMETRY_HZ is back). At N = 100 the climb's 10 Hz samples were most of
# the swarm's start-up CPU (issue 25); a companion asks for what it needs, as here.
CLIMB_TELEMETRY_HZ = 2.0
# The climb is over this close below the take-off altitude, once level (or, on PX4, once PX4
# has ended AUTO.TAKEOFF itself: `_take_off`). Not tighter: PX4 ends AUTO.TAKEOFF as soon as it
# is within NAV_MC_ALT_RAD (0.8 m by default) and a real PX4 SIH has held 0.6 m short for
# minutes (docs/RESULTS.md, session 18); ArduPilot ends at the altitude.
TAKEOFF_REACHED_M = 1.0
TELEMETRY_TIMEOUT_S = 5.0  # wall: flying, a vehicle silent this long is lost
# Lockstep: the world may hold the clock (and so the telemetry) while it waits out a
# straggling agent; the vehicle is lost only if silent much longer than that bound.
LOCKSTEP_TELEMETRY_TIMEOUT_S = 120.0
# Wall: a lockstep agent looks for a lost link or silence this often (a failure of its
# sample handler wakes it at once). Not faster: under load a run's wall time stretches and a
# 10 Hz wall-clock poll in 20 agents cost as many loop turns as the samples (issue 25).
FLY_CHECK_S = 1.0
WATCHDOG_S = 0.1  # wall: re-send the setpoint if telemetry stalls (>= 10 Hz)
UNUSED_STREAMS = {"ATTITUDE": 0.0, "POSITION_TARGET_LOCAL_NED": 0.0, "GLOBAL_POSITION_INT": 1.0}
REENGAGE_EVERY_S = 2.0  # wall: how often to ask for the offboard mode back after a failsafe
# wall: a heartbeat first seen this soon after a mode change was acknowledged may have been
# sent before it (PX4 acknowledges, then its next 1 Hz heartbeat shows the new mode)
MODE_ECHO_S = 0.3
ASK_HOME_EVERY_S = 2.0  # wall: REQUEST_MESSAGE(HOME_POSITION) again while home is not set
NOT_READY_RETRY_S = 1.0  # wall: retry a mode/arm command the autopilot is not ready for
AIRBORNE_M = 2.0  # above home: an armed vehicle higher than this is flying (attach, no takeoff)
# A home farther than this outside the mission area is not a launch site of that mission
# but a wrong --home (ArduPilot SITL's default is Canberra) or a wrong --mission.
FAR_HOME_M = 5_000.0


class Subscription(Protocol):
    """A queue of one message type from the link (`mavlink.client.Subscription`)."""

    queued: Any

    async def next(self, timeout: float = ...) -> Any: ...
    async def newest(self, timeout: float = ...) -> Any: ...
    def close(self) -> None: ...
    def __enter__(self) -> Subscription: ...
    def __exit__(self, *exc: object) -> None: ...


class Link(Protocol):
    """The MAVLink link to the autopilot, as the agent uses it (`mavlink.client.VehicleLink`)."""

    personality: Personality | None  # from the autopilot's heartbeat, once open
    latest: dict[str, Any]  # the latest message of each type

    @property
    def sysid(self) -> int: ...
    @property
    def is_open(self) -> bool: ...
    async def open(self, timeout: float = ...) -> None: ...
    def close(self) -> None: ...
    def subscribe(self, mtype: str, pred: Callable[[Any], bool] | None = ...) -> Subscription: ...
    async def recv(self, mtype: str, timeout: float = ..., pred: Callable[[Any], bool] | None = ...) -> Any: ...
    async def request_message(self, msgid: int, timeout: float | None = ...) -> None: ...
    async def set_message_interval(self, message: str | int, hz: float) -> None: ...
    async def set_mode(self, name: str) -> None: ...
    async def arm(self, force: bool = ...) -> None: ...
    async def takeoff(self, alt_rel_m: float | None = ..., home_amsl_m: float | None = ...) -> None: ...
    def send_accel_ned(self, north: float, east: float, down: float, time_boot_ms: int = ...) -> None: ...
    def send_heartbeat(self) -> None: ...


def far_home_error(mission: Mission, sysid: int, lat: float, lon: float, alt: float) -> UserError | None:
    """A UserError naming both positions if a home at (lat, lon) lies more than FAR_HOME_M
    outside the mission area; None if it is near enough to fly to."""
    o, area = mission.origin, mission.area
    north, east, _ = geodetic_to_ned(o.lat_deg, o.lon_deg, o.alt_m, lat, lon, alt)
    outside = math.hypot(max(0.0, -north, north - area.north_m), max(0.0, -east, east - area.east_m))
    if outside <= FAR_HOME_M:
        return None
    # Great-circle distance for the message: the flat-earth offsets mean nothing this far out.
    p1, p2, dl = math.radians(o.lat_deg), math.radians(lat), math.radians(lon - o.lon_deg)
    c = math.sin(p1) * math.sin(p2) + math.cos(p1) * math.cos(p2) * math.cos(dl)
    km = EARTH_RADIUS_M * math.acos(max(-1.0, min(1.0, c))) / 1000.0
    return UserError(
        f"vehicle {sysid}'s home {lat:.6f}, {lon:.6f} ({alt:.0f} m) is {km:,.0f} km from the mission "
        f"{mission.name!r} (origin {o.lat_deg:.6f}, {o.lon_deg:.6f}, {o.alt_m:.0f} m): start the autopilot at the "
        "mission's launch point (ArduPilot SITL: --home LAT,LON,ALT,HEADING) or pass the mission it flies (--mission)"
    )


class VehicleSession:
    def __init__(self, link: Link, cfg: AgentConfig, clock: MissionClock, decision: Decision, stats: LoopStats,
                 t_proc0: float, on_telemetry: Callable[[Any], None]) -> None:
        self.link, self.cfg, self.clock, self.decision, self.stats = link, cfg, clock, decision, stats
        # The LOCAL_POSITION_NED rate asked for in flight, and so the setpoint rate.
        self.telemetry_hz = stats.telemetry_hz = LOCKSTEP_TELEMETRY_HZ if cfg.lockstep else TELEMETRY_HZ
        self.view = VehicleView(link)  # heartbeat, home and optional requests, as every follower reads them
        self.t_proc0 = t_proc0  # unix time the process started (start-up is counted from it)
        self.on_telemetry = on_telemetry  # each LOCAL_POSITION_NED goes here
        self.vm = cfg.mission.vehicle_model()
        self.started = False  # start() has begun using the link
        self.personality: Personality | None = None  # once the autopilot is found
        self.origin = torch.zeros(3)  # the vehicle's local NED origin in the mission frame
        self._origin_np = self.origin.numpy()  # the same, for the per-sample sum
        self.home_local = (0.0, 0.0, 0.0)  # the vehicle's home in its local NED frame
        self.positions: Subscription | None = None  # LOCAL_POSITION_NED, from start-up on
        self.flying = False  # streaming setpoints
        self.last_send_wall = 0.0
        self.reengaged = 0
        self.leave_to_autopilot = False  # stop without commanding the stop mode (Agent.release)
        self._last_reengage = 0.0
        # The heartbeat in hand and when this session first saw it: a mode change's
        # acknowledgement makes every heartbeat seen until then (or just after) stale.
        self._hb: Any = None
        self._hb_seen = -math.inf
        self._mode_acked = -math.inf
        self._reengage_task: asyncio.Task | None = None

    def mission_state(self, m: Any) -> np.ndarray:
        """(6,) float32 [p, v] in the mission frame from a LOCAL_POSITION_NED.

        Once per telemetry sample: numpy only (`Decision.observe` makes a torch view when a
        second reads it; torch calls on a 6-vector cost more than the rest of the answer);
        the float32 sum is the same IEEE addition torch would do, bit for bit."""
        state = np.array((m.x, m.y, m.z, m.vx, m.vy, m.vz), dtype=np.float32)
        state[:3] += self._origin_np
        return state

    def height_above_home(self) -> float:
        """Metres above home, from the latest telemetry (the local frame: no geodesy)."""
        ego_local_down = float(self.decision.ego[2] - self.origin[2])
        return self.home_local[2] - ego_local_down

    # ------------------------------------------------------------------ setpoints
    def send_setpoint(self, time_boot_ms: int = 0) -> None:
        """The command in force; `time_boot_ms` (lockstep): the telemetry it answers."""
        if time_boot_ms:
            self.link.send_accel_ned(*self.decision.command(), time_boot_ms=time_boot_ms)
        else:
            self.link.send_accel_ned(*self.decision.command())
        self.last_send_wall = time.perf_counter()

    async def watchdog(self) -> None:
        """>= 10 Hz wall even if telemetry stalls (PX4 leaves OFFBOARD after 1 s without)."""
        while True:
            await asyncio.sleep(WATCHDOG_S / 2)
            if self.flying and time.perf_counter() - self.last_send_wall >= WATCHDOG_S:
                self.send_setpoint()

    async def gcs_heartbeat(self) -> None:
        """A companion computer announces itself at 1 Hz (autopilots track their peers).
        Not before the link is up: a TCP connection (ArduPilot SITL's SERIAL0) can take
        seconds while the autopilot is busy, and `open` says hello itself meanwhile."""
        while True:
            if self.started and self.link.is_open:
                self.link.send_heartbeat()
            await asyncio.sleep(1.0)

    # ------------------------------------------------------------------ startup
    async def _telemetry(self, timeout: float | None = None) -> None:
        """Hand the newest position to the agent (older queued ones are stale)."""
        assert self.positions is not None
        if timeout is None:
            timeout = LOCKSTEP_TELEMETRY_TIMEOUT_S if self.cfg.lockstep else TELEMETRY_TIMEOUT_S
        self.on_telemetry(await self.positions.newest(timeout))

    async def _wait_until(self, what: str, cond: Callable[[], bool], timeout_s: float) -> None:
        """Wait on telemetry until cond() holds; timeout in VEHICLE seconds (speedup-safe)."""
        start = self.clock.boot_s
        while not cond():
            await self._telemetry()
            if self.clock.boot_s - start > timeout_s:
                raise VehicleTimeout(self.link.sysid, what, timeout_s)

    async def _set_mode(self, name: str) -> None:
        for attempt in range(5):
            try:
                await self.link.set_mode(name)
                self._mode_acked = time.perf_counter()
                self._hb = self.link.latest.get("HEARTBEAT")  # sent before the switch, whenever it arrived
                self._hb_seen = -math.inf
                return
            except CommandRejected as exc:
                if exc.result_name != "MAV_RESULT_TEMPORARILY_REJECTED" or attempt == 4:
                    raise
                await asyncio.sleep(0.2)

    def _waiting(self, bound_s: float, what: str) -> None:
        log.info("waiting up to %g s for %s", bound_s, what)

    async def _find_autopilot(self) -> Personality:
        cfg, link = self.cfg, self.link
        bound = cfg.bounds.heartbeat_s
        self._waiting(bound, f"an autopilot heartbeat on {cfg.connect_url}")
        try:
            await link.open(timeout=bound)
        except VehicleTimeout as exc:
            raise UserError(f"no autopilot heartbeat on {cfg.connect_url} within {bound:g} s "
                            "(is the autopilot running, and is this its address?)") from exc
        assert link.personality is not None
        p = link.personality
        if cfg.autopilot != "auto" and cfg.autopilot != p.name:
            raise UserError(f"--autopilot {cfg.autopilot}, but the vehicle's heartbeat says {p.name}")
        log.info("vehicle sysid %d on %s: %s personality (heartbeat at %.2f s)", link.sysid, cfg.connect_url, p.name,
                 time.time() - self.t_proc0)
        return p

    async def _wait_home(self) -> Any:
        """HOME_POSITION, asked for every ASK_HOME_EVERY_S: an autopilot without a home yet
        (no GPS fix, EKF origin not set) accepts the request and sends nothing."""
        link, bound = self.link, self.cfg.bounds.home_s
        self._waiting(bound, "the autopilot's home position (set once it has a GPS fix and an EKF origin)")
        t_end = time.monotonic() + bound
        with link.subscribe("HOME_POSITION") as homes:
            while True:
                await self.view.request(HOME_POSITION_ID)
                left = t_end - time.monotonic()
                try:
                    return await homes.next(max(0.0, min(ASK_HOME_EVERY_S, left)))
                except VehicleTimeout:
                    if time.monotonic() >= t_end:
                        raise VehicleTimeout(link.sysid, "HOME_POSITION (the autopilot has not set its home)", bound) from None

    def _place(self, home: Any) -> None:
        """Where the vehicle's local frame lies in the mission frame, from its home: known
        geodetically (lat, lon, alt) and in the local frame (x, y, z; ArduPilot's EKF origin
        need not be the home). A home far outside the mission area is a UserError."""
        o = self.cfg.mission.origin
        placed = place_home(o.lat_deg, o.lon_deg, o.alt_m, home)
        err = far_home_error(self.cfg.mission, self.link.sysid, placed.lat_deg, placed.lon_deg, placed.alt_m)
        if err is not None:
            raise err
        self.home_local = placed.local
        self.origin = torch.tensor(placed.origin, dtype=torch.float32)
        self._origin_np = self.origin.numpy()

    async def _wait_position(self) -> None:
        bound = self.cfg.bounds.position_s
        self._waiting(bound, "the autopilot's local position (LOCAL_POSITION_NED: streamed once its EKF uses GPS)")
        try:
            await self._telemetry(bound)
        except VehicleTimeout:
            raise VehicleTimeout(self.link.sysid, "LOCAL_POSITION_NED (the autopilot has no position estimate)", bound) from None

    async def _armed(self) -> bool:
        """The ARMED flag of the autopilot's next heartbeat (another component's does not count).
        Lockstep: heartbeats follow the vehicle clock, which the world holds until it has
        forked every agent (minutes for 100 agents on a loaded machine: issue 25), so the
        heartbeat bound applies (`program.LOCKSTEP_STARTUP_WAIT_S`)."""
        return (await self.view.next_state(self.cfg.bounds.heartbeat_s if self.cfg.lockstep else 3.0)).armed

    async def _until_ready(self, what: str, step: Callable[[], Awaitable[None]]) -> None:
        """Run `step` until the autopilot accepts it: a refusal other than UNSUPPORTED means
        "not ready yet" (pre-arm checks, an EKF still converging) and is retried every
        NOT_READY_RETRY_S for at most bounds.arm_s; the timeout names the last refusal and
        what the autopilot last said (its STATUSTEXT, e.g. "PreArm: ...")."""
        bound = self.cfg.bounds.arm_s
        self._waiting(bound, f"the autopilot to accept {what} (its pre-arm checks to pass)")
        t_end = time.monotonic() + bound
        with self.link.subscribe("STATUSTEXT") as texts:
            while True:
                try:
                    await step()
                    return
                except CommandRejected as exc:
                    if exc.result_name == "MAV_RESULT_UNSUPPORTED":
                        raise
                    if time.monotonic() >= t_end:
                        said = f", it said {texts.queued[-1].text!r}" if texts.queued else ""
                        raise VehicleTimeout(self.link.sysid, f"acceptance of {what} (last: {exc.result_name}{said})", bound) from exc
                await asyncio.sleep(NOT_READY_RETRY_S)

    async def _take_off(self, p: Personality, home_amsl_m: float) -> None:
        link, alt_tgt = self.link, min(max(self.vm.takeoff_alt_m, self.vm.min_alt_m), self.vm.max_alt_m)
        if p.takeoff_needs_offboard_mode:  # ArduPilot: GUIDED, arm, NAV_TAKEOFF

            async def guided_and_armed() -> None:
                await self._set_mode(p.offboard_mode)
                await link.arm()

            await self._until_ready(f"{p.offboard_mode} and arming", guided_and_armed)
            await link.takeoff(alt_tgt)
        else:  # PX4: arm, AUTO.TAKEOFF, then OFFBOARD once the stream is up
            await self._until_ready("arming", link.arm)
            await link.takeoff(alt_tgt, home_amsl_m=home_amsl_m)
            # Stream from now on: AUTO.TAKEOFF ignores the setpoints, but PX4 sees the offboard
            # signal all along, so the switch to OFFBOARD at the top has no gap to wait out.
            # Before the mission the command damps the motion (hold point: where it is).
            self.decision.hold_target = None
            self.flying = True
        log.info("taking off to %.0f m above home", alt_tgt)
        slowed = await self.view.stream("LOCAL_POSITION_NED", CLIMB_TELEMETRY_HZ)  # refused: the climb at the full rate
        # PX4 judges its take-off on its own estimate against the AMSL target it was given, so
        # the height read here against home can stay more than TAKEOFF_REACHED_M short for good
        # (a real SIH held 1.4 m short: it set its home again at arming, on one noisy GPS fix).
        # So its own end of the take-off mode counts too: the take-off mode, then the hold mode.
        # Watched at every sample, climbing or not, so the take-off mode is seen; the hold mode
        # counts only after it, so a heartbeat from before the command is not taken for the end.
        seen_takeoff = False

        def climbed() -> bool:
            nonlocal seen_takeoff
            state = self.view.latest_state()
            mode = None if state is None else state.mode
            seen_takeoff = seen_takeoff or (p.takeoff_mode is not None and mode == p.takeoff_mode)
            ended = seen_takeoff and mode == p.hold_mode and state is not None and state.armed
            level = abs(float(self.decision.ego[5])) < 0.3
            return level and (self.height_above_home() >= alt_tgt - TAKEOFF_REACHED_M or ended)

        await self._wait_until("takeoff", climbed, self.cfg.takeoff_timeout_s)
        if slowed:  # the offboard switch and the mission need the full rate: not optional
            await link.set_message_interval("LOCAL_POSITION_NED", self.telemetry_hz)

    async def start(self) -> None:
        """Find the autopilot, then take off (or attach) and switch to the offboard mode."""
        cfg, link = self.cfg, self.link
        self.started = True
        p = self.personality = await self._find_autopilot()
        self.positions = link.subscribe("LOCAL_POSITION_NED")
        await link.set_message_interval("LOCAL_POSITION_NED", self.telemetry_hz)
        home = await self._wait_home()
        self._place(home)
        await self._wait_position()
        # Start-up ends here: policy loaded, autopilot found, position and home valid.
        # What follows (arming, climbing) is the vehicle's time, not the agent's.
        self.stats.startup_s = time.time() - self.t_proc0
        log.info("ready after %.2f s (process start -> telemetry and home valid), RSS %.0f MB", self.stats.startup_s, rss_mb())
        # Streams the agent does not use cost the autopilot link (and, in SITL, the
        # world's CPU) for nothing; our MAVLink instance is ours alone, a GCS has its own.
        for name, hz in UNUSED_STREAMS.items():
            await self.view.stream(name, hz)
        # Everything alive now (torch, the policy, the loop) lives for the whole flight:
        # freezing it keeps full GC passes from walking ~10^5 objects mid-decision. Done
        # here, on the ground, because the collection itself takes a while.
        gc.collect()
        gc.freeze()
        armed = await self._armed()
        await self._telemetry()
        height = self.height_above_home()
        if armed and height >= AIRBORNE_M:
            log.info("vehicle armed and %.1f m above home: attaching (no takeoff)", height)
        elif not cfg.takeoff:
            state = f"armed, {height:.1f} m above home" if armed else "disarmed"
            raise UserError(f"--no-takeoff: the vehicle is on the ground ({state}); attach only to a flying vehicle")
        else:
            await self._take_off(p, home.altitude / 1000.0)
        # PX4 refuses OFFBOARD until setpoints stream: stream first (hold here), then switch.
        self.decision.hold_target = self.decision.ego[:3].clone()
        self.flying = True
        for _ in range(5):
            await self._telemetry()
        await self._set_mode(p.offboard_mode)
        log.info("in %s at %.1f m above home, %.2f s after process start", p.offboard_mode, self.height_above_home(),
                 time.time() - self.t_proc0)

    async def common_epoch(self) -> float:
        """t0 on this vehicle's boot clock that every agent of the swarm agrees on, with no
        world to announce it: the last UTC midnight of the autopilot's (GPS-disciplined)
        SYSTEM_TIME. Signalling instants are then multiples of T_up since midnight on every
        vehicle. Without a unix time (no GPS yet) fall back to boot time 0, which agrees
        only between vehicles that booted together (one SITL host)."""
        # Asked for, not only awaited: ArduPilot does not stream SYSTEM_TIME unless told.
        with self.link.subscribe("SYSTEM_TIME") as times:
            try:
                await self.view.request(SYSTEM_TIME_ID)
                st = await times.next(5.0)
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
        """Serve telemetry until `stop` is set (VehicleLost if the vehicle goes silent or its
        link breaks)."""
        if self.cfg.lockstep:
            await self._fly_each_sample(stop)
            return
        while not stop.is_set():
            try:
                await self._telemetry()
            except VehicleUnreachable as exc:  # silent, or its link broke
                raise VehicleLost(exc) from exc
            self._check_mode()

    async def _fly_each_sample(self, stop: asyncio.Event) -> None:
        """Lockstep: every sample is answered, so each is handled as the link parses it
        (`Subscription.handle_with`) instead of waking this task through a future and a
        timeout per sample (issue 25: that round trip was a fixed cost of every answer).
        The world waits for each answer before it sends the next sample, so there is never
        a backlog to skip, and what the agent does is the same. This task only watches for
        a failure of the handler (woken by it), and for silence and a broken link every
        FLY_CHECK_S."""
        positions = self.positions
        assert positions is not None
        failed: list[BaseException] = []
        woken = asyncio.Event()
        last = time.perf_counter()

        def on_position(m: Any) -> None:
            nonlocal last
            if failed:
                return
            last = time.perf_counter()
            try:
                self.on_telemetry(m)
                self._check_mode()
            except Exception as exc:  # noqa: BLE001 - raised by the task below, as the loop did
                failed.append(exc)
                woken.set()

        if positions.queued:
            on_position(await positions.newest(0.0))
        positions.handle_with(on_position)
        try:
            while not stop.is_set():
                if failed:
                    raise failed[0]
                if positions.ended is not None:
                    raise positions.ended
                silent = time.perf_counter() - last
                if silent > LOCKSTEP_TELEMETRY_TIMEOUT_S:
                    raise VehicleLost(VehicleTimeout(self.link.sysid, "LOCAL_POSITION_NED", LOCKSTEP_TELEMETRY_TIMEOUT_S))
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(FLY_CHECK_S):
                        await woken.wait()
        finally:
            positions.handle_with(None)

    def _check_mode(self) -> None:
        """If the autopilot left the offboard mode on its own (a setpoint-loss failsafe
        after a stall of this process), ask for it back once the stream is flowing again,
        at most every REENGAGE_EVERY_S. A mode a pilot chose is left alone: only the
        personality's failsafe hold mode triggers this."""
        now = time.perf_counter()
        hb = self.link.latest.get("HEARTBEAT")
        if hb is not self._hb:
            self._hb, self._hb_seen = hb, now
        if self._hb_seen < self._mode_acked + MODE_ECHO_S:
            return  # the heartbeat may predate our own mode change (issue 28: a false alarm on PX4)
        state = self.view.latest_state()
        p = self.personality
        assert p is not None
        if state is None or state.mode != p.hold_mode or not state.armed:
            return
        if now - self._last_reengage < REENGAGE_EVERY_S or self._reengage_task is not None and not self._reengage_task.done():
            return
        self._last_reengage = now
        self.reengaged += 1
        log.warning("vehicle fell back to %s (setpoint-loss failsafe); re-engaging %s", state.mode, p.offboard_mode)
        self._reengage_task = asyncio.ensure_future(self._reengage(p.offboard_mode))

    async def _reengage(self, mode: str) -> None:
        try:
            async with asyncio.timeout(3.0):
                await self._set_mode(mode)
        except (TimeoutError, VehicleUnreachable, CommandRejected) as exc:
            log.error("could not re-engage %s: %s", mode, exc)

    async def hold(self) -> None:
        """Stop: hand a flying vehicle to the personality's stop mode (PX4 AUTO.LOITER,
        ArduPilot BRAKE). A vehicle its autopilot took over (a failsafe left the offboard
        mode for LAND, say after a GPS loss) or disarmed is left to its autopilot."""
        self._stop_reengaging()  # the stop mode overrides a re-engage still in flight
        if self.personality is None or not self.flying:
            return
        if self.leave_to_autopilot:
            log.warning("stopped: vehicle left to its autopilot (the UAV is out of the mission)")
            return
        now = self.view.latest_state()
        if now is not None and (not now.armed or now.mode == self.personality.land_mode):
            log.warning("stopped: vehicle left to its autopilot (%s, %s)", now.mode, "armed" if now.armed else "disarmed")
            return
        mode = self.personality.stop_mode
        try:
            async with asyncio.timeout(3.0):
                await self._set_mode(mode)
            log.warning("stopped: vehicle in %s", mode)
        except (TimeoutError, VehicleUnreachable, CommandRejected) as exc:
            log.error("stopped, but could not command %s: %s (the autopilot's own failsafe takes over)", mode, exc)

    def _stop_reengaging(self) -> None:
        """Cancel a re-engage task still waiting for its mode's acknowledgement: it runs
        outside the agent's task group, and once the link is closed its next resend would
        fail with nobody to hear it ("Task exception was never retrieved")."""
        if self._reengage_task is not None and not self._reengage_task.done():
            self._reengage_task.cancel()

    def close(self) -> None:
        self._stop_reengaging()
        if self.positions is not None:
            self.positions.close()
        if self.started:
            self.link.close()
