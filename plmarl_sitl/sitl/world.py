"""The SITL world process: autopilots, ground users, link emulator and metrics on one clock.

`SitlWorld` hosts the autopilot emulator's vehicles in-process (`AutopilotHost`), or, with
`WorldConfig.external` (one MAVLink URL per vehicle), runs the mission on autopilots that
fly elsewhere (real ArduCopter SITLs, real drones; `sitl.external`). Either way
(`sitl.vehicles.WorldVehicles`) it is a composition of small parts, each with one job:

* `pacer`: the clock, one interface over three: free-running at wall x speedup, following
  external vehicles' clocks, or lockstep with the agents (`sitl.lockstep`);
* `ground.Ground`: the twin's ground truth on the true positions: users, coverage C(t) and
  lambda_2, each vehicle's sensed users, the demand map;
* `network.relay.Relay`: the signal relay, next to the link emulator: instants, the
  latency queue, the closed markers;
* `outbox.Outbox`: what goes to the agents on the bus, through a broker outage a lockstep
  world emulates;
* `start.StartGate`: when mission time starts (every vehicle flying under its agent);
* `mission_events.EventDispatcher`: the mission's events, where the world and the
  launcher each register their handlers;
* `fault_watch.FaultWatch`: what a vehicle under an autopilot fault says and does.

The world itself does the work of each whole second, the twin's per-second work with the
twin's code: the users step, truth is measured, the vehicles' sensed users and the metrics
(`metrics`: coverage, lambda_2, per-UAV truth, JSON) go out, the second's events apply.

Mission time starts when every vehicle is flying under its agent: the world then
announces `t0` on the retained `start` topic (`sitl.start`), with map 0.

Mission events come from the mission's one schedule (`model.events.EventSchedule`, the
twin's too), given as `WorldConfig.events`: at each mission second the world applies the
changes it owns (node failure: the vehicle; link blackout: the link emulator; GNSS noise:
the vehicles' navigation; T_up change: the `ctl` topic; autopilot faults). The launcher
registers the rest on the same dispatcher (a failed node's agent process, the broker gate).
"""

from __future__ import annotations

import asyncio
import dataclasses
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import torch

from plmarl_sitl.deploy.mqtt.auth import SwarmKey
from plmarl_sitl.deploy.mqtt.schema import Topics, encode_json
from plmarl_sitl.deploy.mqtt.transport import MqttBus
from plmarl_sitl.deploy.mqtt.wire import Wire
from plmarl_sitl.errors import UserError
from plmarl_sitl.mission import Event, Mission
from plmarl_sitl.model.events import Change, EventSchedule, end_second
from plmarl_sitl.sitl.autopilot.host import AutopilotHost
from plmarl_sitl.sitl.external import ExternalVehicles
from plmarl_sitl.sitl.fault_watch import FaultWatch
from plmarl_sitl.sitl.ground import Ground
from plmarl_sitl.sitl.mission_events import EventDispatcher
from plmarl_sitl.sitl.network.link_emulator import LinkEmulator
from plmarl_sitl.sitl.network.relay import Relay
from plmarl_sitl.sitl.options import WorldOptions
from plmarl_sitl.sitl.outbox import Outbox
from plmarl_sitl.sitl.pacer import FollowPacer, FreePacer, LockstepPacer, Pacer
from plmarl_sitl.sitl.start import MissionTime, StartGate
from plmarl_sitl.sitl.vehicles import EmulatedVehicles, WorldVehicles
from plmarl_sitl.twin.env import launch_positions

if TYPE_CHECKING:
    from plmarl_sitl.sitl.agents import AgentFleet

log = logging.getLogger("plmarl.world")


@dataclass(frozen=True)
class WorldConfig(WorldOptions):
    """A world's options (`sitl.options`: declared once, with the `plmarl world` flags) and
    what the program that builds it loads or decides."""

    mission: Mission
    broker_url: str
    bind_host: str = "127.0.0.1"  # the vehicles' UDP ports listen here (a swarm over hosts: the launcher's address)
    tick_hz: float = 50.0
    start_margin_s: float = 2.0  # t0 is at least this far ahead of the announcement (sim s) ...
    start_margin_wall_s: float = 0.5  # ... and at least this much wall time (x speedup) ahead
    start_timeout_s: float = 300.0  # sim s: start anyway with whoever is ready
    publish_sense: bool = True  # False: no sensing publisher (a vehicle without the sensor)
    events: EventSchedule | None = None  # mission events to apply (the launcher's run); None: none
    # The swarm key: the world relays only states that authenticate and signs what it
    # sends the agents (start, ctl, closed, sense, demand); None: the unsigned wire.
    swarm_key: SwarmKey | None = None
    broker_credentials: tuple[str, str] | None = None  # (username, password) on the broker
    # MAVLink 2 signing keys, one per vehicle (empty: unsigned links). The emulated vehicle
    # i signs with key i and drops unsigned or badly signed input; with external vehicles
    # the world's own link to vehicle i signs with it.
    mavlink_keys: tuple[bytes, ...] = ()

    def __post_init__(self) -> None:
        super().__post_init__()
        n = self.n_uavs or self.mission.n_uavs
        if self.external and len(self.external) != n:
            raise UserError(f"--external: {len(self.external)} URL(s) for {n} UAVs (one per UAV; or set --n-uavs)")


@dataclass
class WorldSummary:
    t0_boot_s: float | None = None
    coverage: list[float] = field(default_factory=list)  # C(t) for mission seconds 1, 2, ...
    lambda2: list[float] = field(default_factory=list)
    wall_s: float = 0.0
    sim_s: float = 0.0
    links: dict[str, int] = field(default_factory=dict)
    # Wall seconds from mission second 0 to the last: the pace actually achieved. A free
    # world that cannot keep its --speedup falls behind (bounded catch-up), so the nominal
    # speedup overstates it on a loaded machine.
    mission_wall_s: float | None = None
    not_ready_at_start: list[str] = field(default_factory=list)  # vehicles left behind by the start timeout

    @property
    def mean_coverage(self) -> float:
        return sum(self.coverage) / len(self.coverage) if self.coverage else float("nan")


def blackout_pairs(ev: Event, n: int) -> list[tuple[int, int]] | None:
    """The links a link_blackout cuts: all of them, or every link touching `uavs`."""
    if not ev.uavs:
        return None
    return sorted({(min(u, j), max(u, j)) for u in ev.uavs for j in range(n) if j != u})


class SitlWorld:
    def __init__(self, cfg: WorldConfig, on_metrics: Callable[[dict], None] | None = None,
                 on_event: Callable[[dict], None] | None = None) -> None:
        self.cfg = cfg
        m = cfg.mission
        self.n = cfg.n_uavs or m.n_uavs
        if self.n != m.n_uavs:
            m = dataclasses.replace(m, n_uavs=self.n)
        self.mission = m
        self.on_metrics = on_metrics
        self.on_event = on_event
        self.on_agent_failed: Callable[[int, int | None, str], None] | None = None  # (uav, mission s, why)
        self.on_behind: Callable[[str], None] | None = None  # free-running: the once-per-run "running behind"
        # Before the mission starts, at each whole boot second: the vehicles not yet flying under
        # their agents (`StartGate.not_ready`), so a launcher can say what start-up waits for.
        self.on_waiting: Callable[[float, list[str]], None] | None = None
        # Lockstep: which of these agents are still computing (`AgentFleet.working`); one that
        # is, is not a straggler yet (None: every agent overdue is one).
        self.agents_working: Callable[[list[int]], list[int]] | None = None
        self.topics = Topics(cfg.swarm)
        vm = m.vehicle_model()
        self.takeoff_alt = min(max(vm.takeoff_alt_m, vm.min_alt_m), vm.max_alt_m)  # the twin's start altitude
        self.host: AutopilotHost | None = None  # the emulated autopilots, if they are
        self.vehicles: WorldVehicles = self._vehicles()
        seed = m.seed if cfg.seed is None else cfg.seed
        self.links = LinkEmulator(m, self.n, loss=cfg.loss, seed=seed)
        self.wire = Wire(cfg.swarm_key)
        self.time = MissionTime(tup_s=m.signalling.tup_s)
        self.bus = MqttBus(cfg.broker_url, f"plmarl-world-{cfg.swarm}", [self.topics.tx("+")], self._on_state,
                           name="world-bus", credentials=cfg.broker_credentials)
        self.bus.on_connection = self._on_bus_connection
        self.outbox = Outbox(self.bus, cfg.events if cfg.lockstep else None)
        # A retained start (and T_up) of a previous run must not reach this run's agents.
        for topic in (self.topics.start, self.topics.ctl, self.topics.demand, *((self.topics.tick,) if cfg.lockstep else ())):
            self.outbox.publish_sticky(topic, b"")
        self.ground = Ground(m, seed, self.outbox, self.wire, self.topics, cfg.publish_sense)
        self.relay = Relay(self.links, self.vehicles, self.outbox, self.wire, self.topics, self.time,
                           latency_s=cfg.latency_s, speedup=cfg.speedup,
                           lockstep_wake=self._state_held if cfg.lockstep and self.host else None)
        self.start_gate = StartGate(self.vehicles, self.takeoff_alt, cfg.start_timeout_s,
                                    max(cfg.start_margin_s, cfg.start_margin_wall_s * cfg.speedup))
        self.pacer: Pacer = self._pacer()
        self.events = EventDispatcher(cfg.events)
        self.faults = FaultWatch(self.vehicles, self.time)
        self._register_event_handlers()
        self.summary = WorldSummary()
        self.ctl_seq = 0
        self.stopping = asyncio.Event()
        self.started_wall: float | None = None
        self.failed_agents: set[int] = set()  # agents declared failed (agent_failed), in either pace

    def _state_held(self) -> None:
        assert isinstance(self.pacer, LockstepPacer)
        self.pacer.state_held()

    def _vehicles(self) -> WorldVehicles:
        cfg, m = self.cfg, self.mission
        if cfg.external:
            return ExternalVehicles(m, list(cfg.external), cfg.speedup, list(cfg.mavlink_keys) or None)
        homes = launch_positions(m, 0.0)
        homes[:, 2] = 0.0
        self.host = AutopilotHost(
            self.n,
            personality_name=cfg.personality,
            vehicle=m.vehicle,
            origin=m.origin,
            home_offsets_ned=[tuple(map(float, h)) for h in homes],
            base_port=cfg.base_port,
            bind_host=cfg.bind_host,
            boot=cfg.boot,
            signing_keys=list(cfg.mavlink_keys) or None,
            # A swarm's vehicles hold where they are when their agent's setpoints stop
            # (PX4 COM_OBL_RC_ACT 5; its default, without RC, flies home: issue 28).
            # The airframe is the mission's vehicle model, the twin's point mass (one model
            # of the world): no SIH airframe drag (SIH_KDV 0). `plmarl autopilot` keeps
            # SIH's drag, as real PX4 SIH flies (docs/CONFORMANCE.md).
            params={"offboard_loss_action": 5, "accel_drag_per_s": 0.0},
            # Lockstep: every vehicle's telemetry on the same grid points, so all agents
            # answer (and decide) in parallel at each barrier instead of in 5 serial groups.
            **({"stream_phases": 1} if cfg.lockstep else {}),
        )
        return EmulatedVehicles(self.host)

    def _pacer(self) -> Pacer:
        cfg = self.cfg
        if cfg.lockstep:
            assert self.host is not None
            return LockstepPacer(self, self.host, cfg.straggler_s, cfg.speedup)
        if self.vehicles.owns_clock:
            return FreePacer(self, cfg.speedup, cfg.tick_hz)
        return FollowPacer(self)

    # ------------------------------------------------------------------ the mission clock, for readers
    @property
    def lockstep(self) -> bool:
        return self.cfg.lockstep

    @property
    def t0(self) -> float | None:
        """Boot second of mission t = 0 (external vehicles: on the reference clock); None before the start."""
        return self.time.t0

    @property
    def t0_by_uav(self) -> list[float] | None:
        return self.time.t0_by_uav

    @property
    def mission_t(self) -> int | None:
        """The last whole mission second processed."""
        return self.time.k

    @property
    def tup_s(self) -> int:
        return self.time.tup_s

    # ------------------------------------------------------------------ events
    def _register_event_handlers(self) -> None:
        """The world's part of the mission's events (the launcher registers its own)."""
        ev = self.events
        ev.on("node_failure", self._on_node_failure)
        ev.on("link_blackout", self._on_link_blackout)
        ev.on("tup_change", self._on_tup_change)
        ev.on("gnss_noise", self._on_gnss_noise)
        ev.on("gps_loss", self._on_gps_loss)
        ev.on("motor_failure", self._on_motor_failure)
        ev.on_fault_failure(self._on_fault_failure)

    def _on_node_failure(self, change: Change) -> None:
        if change.event.uav is not None and not change.ends:
            self.kill(change.event.uav)

    def _on_link_blackout(self, change: Change) -> None:
        if not change.ends:  # the cut itself expires at the end second
            self.cut_links(blackout_pairs(change.event, self.n), end_second(change.event) - change.second)

    def _on_tup_change(self, change: Change) -> None:
        if change.event.tup_s is not None:
            self.set_tup(change.event.tup_s)

    def _on_gnss_noise(self, change: Change) -> None:
        schedule = self._schedule()
        std = schedule.gnss_std_m(change.second)
        for u in schedule.uavs_of(change.event):
            self.vehicles.set_gnss_noise(u, std[u])

    def _on_gps_loss(self, change: Change) -> None:
        schedule = self._schedule()
        dark = {u for e in schedule.active("gps_loss", change.second) for u in schedule.uavs_of(e)}
        for u in schedule.uavs_of(change.event):
            self.faults.watch(u)
            self.vehicles.set_gps(u, u not in dark)  # overlapping losses: dark while any lasts

    def _on_motor_failure(self, change: Change) -> None:
        if change.event.uav is not None:
            self.faults.watch(change.event.uav)
            self.vehicles.fail_motor(change.event.uav)

    def _on_fault_failure(self, u: int, ev: Event, second: int) -> None:
        self.vehicles.mark_failed(u)
        log.warning("event: vehicle %d out of the mission at t=%d s (%s): left to its autopilot", u, second, ev.type)

    def _schedule(self) -> EventSchedule:
        assert self.events.schedule is not None  # a handler runs only for a schedule's change
        return self.events.schedule

    def _on_bus_connection(self, up: bool) -> None:
        """The world's broker connection broke or came back (a stalled or stopped broker, a
        scripted outage): recorded as `broker_lost` / `broker_back` at the mission second.
        The physics and telemetry do not wait for it; the agents fly on their predictions."""
        if self.time.k is None or self.on_event is None or self.stopping.is_set():
            return  # before the mission the start-up waits for the bus anyway; after it the broker is stopped on purpose
        entry = {"t": float(self.time.k), "type": "broker_back" if up else "broker_lost"}
        log.warning("world: %s at t = %d s", "broker connection back" if up else "lost the broker connection", self.time.k)
        self.on_event(entry)

    def kill(self, i: int) -> None:
        """Node failure: vehicle i goes silent and falls; it stops covering and relaying."""
        self.vehicles.kill(i)
        log.warning("event: vehicle %d killed at boot %.1f s", i, self.now)

    def cut_links(self, pairs: list[tuple[int, int]] | None, duration_s: float) -> None:
        """Cut some links (None: all) for `duration_s` sim seconds."""
        self.links.cut(pairs, self.now + duration_s)
        log.warning("event: links %s cut for %.1f s", "all" if pairs is None else pairs, duration_s)

    def set_tup(self, tup_s: int) -> None:
        """Tell the agents to signal every `tup_s` seconds from now on (ctl topic)."""
        self.time.tup_s = int(tup_s)
        self.ctl_seq += 1  # signed: agents apply only a ctl newer than the last (a replay is not)
        ctl = {"tup_s": self.time.tup_s, "seq": self.ctl_seq} if self.wire.signed else {"tup_s": self.time.tup_s}
        self.outbox.publish_retained(self.topics.ctl, self.wire.json("ctl", ctl))

    def agent_failed(self, i: int, why: str) -> None:
        """Agent i is gone (its process died, or in lockstep it stopped answering): recorded
        once; lockstep stops waiting for it. Its vehicle is left to its setpoint-loss failsafe."""
        if i in self.failed_agents:
            return
        self.failed_agents.add(i)
        self.pacer.agent_failed(i, why)
        log.warning("agent %d declared failed (%s) at boot %.2f s; its vehicle is left to its failsafe", i, why, self.now)
        if self.on_agent_failed is not None:
            self.on_agent_failed(i, self.time.k, why)

    def running_behind(self, msg: str) -> None:
        """The free-running clock cannot keep its --speedup: said once per run (`pace.Pace`)."""
        log.warning("%s", msg)
        if self.on_behind is not None:
            self.on_behind(msg)

    # ------------------------------------------------------------------ state
    @property
    def now(self) -> float:
        """The vehicles' clock, boot seconds (the emulator's, or the external vehicles' reference)."""
        return self.vehicles.now

    def alive(self) -> torch.Tensor:
        return self.vehicles.alive()

    def positions(self) -> torch.Tensor:
        """(N, 3) float32 mission-frame positions (what the twin's coverage code takes)."""
        return self.vehicles.positions().to(torch.float32)

    def not_ready(self) -> list[str]:
        """Why the mission cannot start yet: one entry per vehicle not flying under its agent."""
        return self.start_gate.not_ready()

    def _on_state(self, topic: str, payload: bytes) -> None:
        self.relay.on_message(topic, payload)

    # ------------------------------------------------------------------ per-second work
    def whole_second(self, second: float) -> None:
        """The pacer reached a whole boot second: its work, then the start if it is due."""
        self._second(second)
        if self.time.t0 is None:
            self._maybe_start(second)

    def _maybe_start(self, second: float) -> None:
        due = self.start_gate.t0_at(second, self.now)
        if due is None:
            if self.on_waiting is not None:
                self.on_waiting(second, self.start_gate.not_ready())
            return
        t0, left_behind = due
        if left_behind:
            self.summary.not_ready_at_start = left_behind
        self.time.t0 = t0
        self.summary.t0_boot_s = t0
        self.pacer.start_at(t0)
        self.time.t0_by_uav = self.vehicles.start_times(t0)
        start = {"t0_boot_s": t0, "tup_s": self.time.tup_s, "n_uavs": self.n}
        if self.time.t0_by_uav is not None:
            start["t0_boot_s_by_uav"] = self.time.t0_by_uav
        self.outbox.publish_sticky(self.topics.start, self.wire.json("start", start))
        self.ground.publish_start_map()
        log.info("mission starts at boot %.0f s (now %.2f s)%s", t0, self.now,
                 f"; on each vehicle's clock {self.time.t0_by_uav}" if self.time.t0_by_uav is not None else "")

    def _second(self, second: float) -> None:
        """Work at a whole second: mission second k = second - t0 (or a boot second before t0)."""
        k: int | None = None
        if self.time.t0 is not None and second >= self.time.t0 - 1e-6:
            k = int(round(second - self.time.t0))
            self.outbox.begin_second(k)
            self.ground.step_to(k)
            self.time.k = k
        pos = self.positions()
        alive = self.alive()
        truth = self.ground.measure(pos, alive)
        if k is not None and k >= 1:
            self.summary.coverage.append(truth.coverage)
            self.summary.lambda2.append(truth.lambda2)
        if k is not None:
            self.ground.sense(k, pos, alive)
        uav = self.vehicles.uav_rows()
        metrics = {
            "t": k,
            "boot_s": round(second, 3),
            "t0_boot_s": self.time.t0,
            "coverage": truth.coverage,
            "lambda2": truth.lambda2,
            "links_up": truth.links_up,
            "uav": uav,
            "link_counters": self.links.counters.as_dict(),
            "tup_s": self.time.tup_s,
        }
        self.outbox.publish(self.topics.metrics, encode_json(metrics))
        if self.host is not None:
            self.host.log_counters()  # dropped MAVLink input (unsigned commands ...): a line when it moves
        if k is not None:
            for entry in self.faults.reports(uav):
                log.info("autopilot fault report: %s", entry)
                if self.on_event is not None:
                    self.on_event(entry)
            self.events.dispatch(k)
        if self.on_metrics is not None:
            self.on_metrics(metrics)
        if k == 0:
            self.time.wall0 = time.perf_counter()
        if k is not None and self.cfg.episode_s is not None and k >= self.cfg.episode_s:
            if self.time.wall0 is not None:
                self.summary.mission_wall_s = time.perf_counter() - self.time.wall0
            self.stopping.set()

    # ------------------------------------------------------------------ lifecycle
    def stop(self) -> None:
        self.stopping.set()

    async def shutdown(self, fleet: AgentFleet | None = None) -> None:
        """Stop the clock, close the vehicles' sockets and stop `fleet`'s agents (whatever
        state the run is in; safe to call twice)."""
        self.stop()
        self.vehicles.close()
        if fleet is not None:
            await fleet.stop()

    async def _flush(self, timeout_s: float) -> None:
        """Let the last metrics go out before the bus closes."""
        try:
            async with asyncio.timeout(timeout_s):
                while self.bus.queued and self.bus.connected.is_set():
                    await asyncio.sleep(0.01)
        except TimeoutError:
            log.debug("bus flush timed out with %d messages queued", self.bus.queued)

    async def start(self) -> None:
        """Bind the emulated vehicles' UDP ports (agents may connect from now on), or start
        following the external ones."""
        await self.vehicles.start()

    async def run(self, keep_sockets: bool = False) -> WorldSummary:
        """Run until `stop()`, the episode ends, or cancellation; then close the vehicles'
        sockets, unless `keep_sockets`: a launcher that still has agents to stop keeps the
        autopilots answering so each agent can command its hold mode (`host.close()` later)."""
        if not self.vehicles.started:
            await self.start()
        # The world's tensors are tiny (N vehicles, a few thousand users): a second torch
        # thread never pays, and its OpenMP pool spinning after each op cost ~12 % of the
        # world's CPU (perf, scale_20; docs/RESULTS.md, issue 25). Restored after the run,
        # for a caller that goes on in this process (tests, `plmarl world` as a library).
        threads = torch.get_num_threads()
        torch.set_num_threads(1)
        t_wall = time.perf_counter()
        self.started_wall = t_wall
        try:
            async with asyncio.TaskGroup() as tg:
                bus = tg.create_task(self.bus.run(), name="world-bus")
                await self.pacer.run()
                await self._flush(1.0)
                bus.cancel()
        finally:
            torch.set_num_threads(threads)
            if not keep_sockets:
                self.vehicles.close()
            self.summary.wall_s = time.perf_counter() - t_wall
            self.summary.sim_s = self.now - self.pacer.sim0 if self.pacer.sim0 is not None else 0.0
            self.summary.links = self.links.counters.as_dict()
        return self.summary
