"""The SITL world process: autopilots, ground users, link emulator and metrics on one clock.

`SitlWorld` hosts the autopilot emulator's vehicles in-process (`AutopilotHost`) and owns
simulated time: wall time x speedup, advanced in chunks that land exactly on every whole
second. Or, with `WorldConfig.external` (one MAVLink URL per vehicle), it runs the mission
on autopilots that fly elsewhere (real ArduCopter SITLs, real drones) and follows their
clocks instead (`sitl.external`): a second is processed once every live vehicle has
reported it. Either way (`sitl.vehicles.WorldVehicles`), at every whole second the twin's
per-second work happens with the twin's code:

* ground users step once per mission second (`world.users.step_users`, same generator
  seeding as `CoverageEnv(mission, 1, seed)`, so the same seed gives the same users);
* coverage C(t) (`world.coverage.covered_users`) and lambda_2 are computed on the true
  mission-frame positions (vehicle local NED + home offset; homes are the twin's launch
  positions at ground level);
* each vehicle's sensed users (within R_s of its true position) go to `sense/<id>`;
* the user-density map (`model.demand.demand_map`, the twin's function) goes to the
  retained `demand` topic for every map instant (`model.demand.is_map_instant`: where
  the twin refreshes its map), each computed from the users at its instant. The twin's
  agents see the map of instant k at k, with no delay; a broker has one (seconds of
  vehicle time with the in-process amqtt on a loaded machine). The users' motion does not
  depend on the UAVs, so the world steps them one map period ahead and publishes the
  map of instant k at k - period (map 0 with the start announcement): it is at the
  agents long before their decision at k, which never uses a map of a later instant
  (and still waits, bounded, for a late one);
* `metrics` carries coverage, lambda_2 and per-UAV truth (JSON).

Signalling is relayed as it arrives: a state on `tx/<j>` goes to `rx/<i>` for every i that
hears j now (`bus.linkemu.LinkEmulator`: R_comm and SINR >= Gamma, cuts, loss), after an
optional latency in sim time.

Mission time starts when every vehicle is flying under its agent (armed, in the offboard
mode, at takeoff altitude; external vehicles: and no longer climbing): the world then
announces `t0` (a whole second, a margin ahead) on the retained `start` topic, and, for
vehicles with clocks of their own, that instant on each one's clock (`t0_boot_s_by_uav`).
Agents count mission seconds from t0 on their own vehicle clock, so the twin's t = 0 (the
launch line at takeoff altitude) is the same instant on both sides.

Mission events come from the mission's one schedule (`model.events.EventSchedule`, the
twin's too), given as `WorldConfig.events`: at each mission second the world applies the
changes it owns (node failure: the vehicle; link blackout: the link emulator; GNSS noise:
the vehicles' navigation; T_up change: the `ctl` topic). The launcher applies the rest
from the same schedule (a failed node's agent process, the broker gate).
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import heapq
import itertools
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import torch

from plmarl_sitl.deploy.mqtt.auth import AuthError, SwarmKey
from plmarl_sitl.deploy.mqtt.schema import (
    INSTANT_WAIT_MIN_S,
    INSTANT_WAIT_WALL_S,
    WINDOW_SLACK_S,
    Malformed,
    SeqFilter,
    Topics,
    encode_json,
)
from plmarl_sitl.deploy.mqtt.transport import MqttBus
from plmarl_sitl.deploy.mqtt.wire import Wire
from plmarl_sitl.mission import Event, Mission
from plmarl_sitl.model.channel import CoverageRadius
from plmarl_sitl.model.coverage import covered_users
from plmarl_sitl.model.demand import demand_map, grid_shape, is_map_instant, map_period
from plmarl_sitl.model.events import EventSchedule, end_second
from plmarl_sitl.model.graph import algebraic_connectivity, link_mask, weighted_adjacency
from plmarl_sitl.model.users import UserState, init_users, step_users
from plmarl_sitl.sitl.autopilot.host import AutopilotHost
from plmarl_sitl.sitl.external import ExternalVehicles
from plmarl_sitl.sitl.lockstep import DEFAULT_STRAGGLER_S, Barrier
from plmarl_sitl.sitl.network.link_emulator import LinkEmulator
from plmarl_sitl.sitl.pace import CATCHUP_TICKS, Pace
from plmarl_sitl.sitl.vehicles import EmulatedVehicles, WorldVehicles
from plmarl_sitl.twin.env import launch_positions

if TYPE_CHECKING:
    from plmarl_sitl.sitl.agents import AgentFleet

log = logging.getLogger("plmarl.world")

CHUNK_S = 0.08  # sim seconds per host.advance between yields (4 substeps at 50 Hz)
FOLLOW_POLL_S = 0.1  # wall: external vehicles silent this long: check the instants and the queue anyway
WAIT_LOG_EVERY_S = 30  # vehicle s: how often the world says what it waits for before the start


@dataclass(frozen=True)
class WorldConfig:
    mission: Mission
    broker_url: str
    swarm: str = "sitl"
    personality: str = "px4"
    boot: str = "instant"  # autopilot start-up: instant, or real (the personality's measured timeline)
    speedup: float = 1.0
    base_port: int = 14540
    bind_host: str = "127.0.0.1"  # the vehicles' UDP ports listen here (a swarm over hosts: the launcher's address)
    seed: int | None = None  # users' seed; None: mission.seed
    loss: float = 0.0  # per-delivery loss probability
    latency_s: float = 0.0  # sim seconds between a tx and its deliveries
    tick_hz: float = 50.0
    start_margin_s: float = 2.0  # t0 is at least this far ahead of the announcement (sim s) ...
    start_margin_wall_s: float = 0.5  # ... and at least this much wall time (x speedup) ahead
    start_timeout_s: float = 300.0  # sim s: start anyway with whoever is ready
    episode_s: int | None = None  # stop after this many mission seconds (None: run until stopped)
    n_uavs: int | None = None  # override mission.n_uavs (tests)
    publish_sense: bool = True  # False: no sensing publisher (a vehicle without the sensor)
    events: EventSchedule | None = None  # mission events to apply (the launcher's run); None: none
    # MAVLink URLs of vehicles that fly elsewhere, one per UAV (then no emulated autopilots:
    # personality, boot and base_port do not apply); empty: the emulator in this process.
    external: tuple[str, ...] = ()
    # The swarm key: the world relays only states that authenticate and signs what it
    # sends the agents (start, ctl, closed, sense, demand); None: the unsigned wire.
    swarm_key: SwarmKey | None = None
    broker_credentials: tuple[str, str] | None = None  # (username, password) on the broker
    # MAVLink 2 signing keys, one per vehicle (empty: unsigned links). The emulated vehicle
    # i signs with key i and drops unsigned or badly signed input; with external vehicles
    # the world's own link to vehicle i signs with it.
    mavlink_keys: tuple[bytes, ...] = ()
    # Lockstep (emulated vehicles only, `sitl.lockstep`): vehicle time waits for every
    # member agent's answer to each telemetry sample and for the tx of each instant; the
    # speedup then paces only the start-up. An agent that owes an answer for straggler_s
    # of wall time is declared failed.
    lockstep: bool = False
    straggler_s: float = DEFAULT_STRAGGLER_S


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
        self.mission = m
        self.n = cfg.n_uavs or m.n_uavs
        if self.n != m.n_uavs:
            import dataclasses

            self.mission = m = dataclasses.replace(m, n_uavs=self.n)
        self.on_metrics = on_metrics
        self.on_event = on_event
        self.faulted: dict[int, tuple[str, bool, bool]] = {}  # UAVs under an autopilot fault: last (mode, armed, position)
        self.topics = Topics(cfg.swarm)
        vm = m.vehicle_model()
        self.vehicle_model = vm
        self.takeoff_alt = min(max(vm.takeoff_alt_m, vm.min_alt_m), vm.max_alt_m)  # the twin's start altitude
        self.host: AutopilotHost | None = None  # the emulated autopilots, if they are
        self.vehicles: WorldVehicles
        self.barrier: Barrier | None = None  # lockstep only
        if cfg.lockstep and cfg.external:
            raise ValueError("lockstep needs emulated vehicles (external autopilots keep clocks of their own)")
        if cfg.external:
            self.vehicles = ExternalVehicles(m, list(cfg.external), cfg.speedup, list(cfg.mavlink_keys) or None)
        else:
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
                # Lockstep: every vehicle's telemetry on the same grid points, so all agents
                # answer (and decide) in parallel at each barrier instead of in 5 serial groups.
                **({"stream_phases": 1} if cfg.lockstep else {}),
            )
            self.vehicles = EmulatedVehicles(self.host)
            if cfg.lockstep:
                self.barrier = Barrier(self.host.fleet, cfg.straggler_s)
        self.radius = CoverageRadius(m.channel, m.radii.sensing_m, vm.min_alt_m, vm.max_alt_m)
        seed = m.seed if cfg.seed is None else cfg.seed
        self.gen = torch.Generator().manual_seed(seed)  # as CoverageEnv(mission, 1, seed)
        self.users: UserState = init_users(m, 1, self.gen, torch.float32)
        self.users_ahead: collections.deque[UserState] = collections.deque()  # users of seconds k + 1 .. k + map period
        self.map_seq = 0
        self.links = LinkEmulator(m, self.n, loss=cfg.loss, seed=seed)
        self.wire = Wire(cfg.swarm_key)
        self.seq_filter = SeqFilter()  # relays each state once: a replay is not relayed again
        self.ctl_seq = 0
        self.bus = MqttBus(cfg.broker_url, f"plmarl-world-{cfg.swarm}", [self.topics.tx("+")], self._on_message, name="world-bus",
                           credentials=cfg.broker_credentials)
        # A retained start (and T_up) of a previous run must not reach this run's agents.
        self.bus.publish(self.topics.start, b"", sticky=True)
        self.bus.publish(self.topics.ctl, b"", sticky=True)
        self.bus.publish(self.topics.demand, b"", sticky=True)
        if cfg.lockstep:
            self.bus.publish(self.topics.tick, b"", sticky=True)
        self.summary = WorldSummary()
        self.t0: float | None = None  # boot second of mission t = 0 (external vehicles: on the reference clock)
        self.t0_by_uav: list[float] | None = None  # ... on each vehicle's own clock, if they differ
        self.mission_t: int | None = None  # last whole mission second processed
        self.tup_s = m.signalling.tup_s
        self._pending: list[tuple[float, int, str, bytes]] = []  # (due sim s, tiebreak, topic, payload)
        self._tiebreak = itertools.count()
        self._instants: dict[float, set[int]] = {}  # open signalling instants: who has signalled
        # Deliveries of each open instant, per receiver: sent as one rx message when the
        # instant closes (N messages per instant instead of N (N - 1) through the broker).
        self._batches: dict[float, dict[int, list[bytes]]] = {}
        self._closed_upto = -math.inf  # instants up to here are closed: late updates go out alone
        self._stop = asyncio.Event()
        self._next_second = 1.0  # boot seconds before t0, mission seconds after
        self.started_wall: float | None = None
        self._t0_wall: float | None = None  # perf_counter at mission second 0
        self._sim0: float | None = None  # the vehicles' clock when the run began (sim_s is counted from it)
        # Lockstep state: the states of each open instant by sender (relayed in sender order
        # when it closes), the boot second whose tick is not yet out, since when (wall) the
        # tick waits for an instant's states, T_up at that second, and the start placement.
        self._held: dict[float, dict[int, bytes]] = {}
        self._tick_due: float | None = None
        self._tx_wait_since: float | None = None
        self._instant_tup = self.tup_s
        self._place_pending = False
        self._bus_cut = False  # lockstep: this second lies in an emulated broker outage
        self._held_retained: dict[str, bytes] = {}  # retained messages held by it (topic -> newest)
        self.on_signal: Callable[[str, bytes], None] | None = None  # lockstep: tx relayed and rx sent, in order
        self.on_agent_failed: Callable[[int, int | None, str], None] | None = None  # (uav, mission s, why)
        # Lockstep: which of these agents are still computing (`AgentFleet.working`); one that
        # is, is not a straggler yet (None: every agent overdue is one).
        self.agents_working: Callable[[list[int]], list[int]] | None = None
        self.bus.on_connection = self._on_bus_connection
        self.failed_agents: set[int] = set()  # agents declared failed (agent_failed), in either pace
        self.pace = Pace(cfg.speedup)  # free-running: mission time lost to the bounded catch-up
        self.on_behind: Callable[[str], None] | None = None  # free-running: the once-per-run "running behind"

    # ------------------------------------------------------------------ events
    def _outage_emulated(self, k: int) -> bool:
        """Lockstep: mission second k lies in a broker outage, which the world emulates.

        A free-running swarm cuts the broker's TCP connections (the launcher's gate), and the
        agents reconnect with a jittered wall-clock backoff: which seconds each one misses
        would then depend on machine load. In lockstep the world instead drops what the
        outage would: no sensing and no relayed state reaches an agent for the outage's
        seconds, and retained messages (the demand map, T_up changes) are held and go out
        when it ends, as a broker's retained copy would reach a reconnecting agent. The
        lockstep tick is the SITL clock, not signalling, and goes on."""
        schedule = self.cfg.events
        return self.barrier is not None and schedule is not None and schedule.broker_down(k)

    def _publish_retained(self, topic: str, payload: bytes) -> None:
        """A retained message, held while an emulated outage lasts (`_outage_emulated`)."""
        if self._bus_cut:
            self._held_retained[topic] = payload  # the newest per topic, as a broker retains
        else:
            self.bus.publish(topic, payload, sticky=True)

    def apply_events(self, second: int) -> None:
        """Apply what the event schedule changes at this mission second, where it is the
        world's to apply (the launcher acts on the same changes for its processes)."""
        schedule = self.cfg.events
        if schedule is None:
            return
        for change in schedule.changes_at(second):
            ev = change.event
            if ev.type == "node_failure" and ev.uav is not None and not change.ends:
                self.kill(ev.uav)
            elif ev.type == "link_blackout" and not change.ends:  # the cut itself expires at the end second
                self.cut_links(blackout_pairs(ev, self.n), end_second(ev) - second)
            elif ev.type == "tup_change" and ev.tup_s is not None:
                self.set_tup(ev.tup_s)
            elif ev.type == "gnss_noise":
                std = schedule.gnss_std_m(second)
                for u in schedule.uavs_of(ev):
                    self.vehicles.set_gnss_noise(u, std[u])
            elif ev.type == "gps_loss":
                dark = {u for e in schedule.active("gps_loss", second) for u in schedule.uavs_of(e)}
                for u in schedule.uavs_of(ev):
                    self._watch_fault(u)
                    self.vehicles.set_gps(u, u not in dark)  # overlapping losses: dark while any lasts
            elif ev.type == "motor_failure" and ev.uav is not None:
                self._watch_fault(ev.uav)
                self.vehicles.fail_motor(ev.uav)
        for u, ev in schedule.fault_failures_at(second):
            self.vehicles.mark_failed(u)
            log.warning("event: vehicle %d out of the mission at t=%d s (%s): left to its autopilot", u, second, ev.type)

    def _watch_fault(self, i: int) -> None:
        if i not in self.faulted:
            row = self.vehicles.uav_rows()[i]
            self.faulted[i] = (row["mode"], row["armed"], self.vehicles.position_streams(i))

    def _report_faults(self, rows: list[dict]) -> None:
        """What the vehicles under a fault said and did since the last second, as events."""
        if self.t0 is None:
            return
        reports = self.vehicles.fault_reports()
        for i, (mode, armed, streams) in self.faulted.items():
            now = (rows[i]["mode"], rows[i]["armed"], self.vehicles.position_streams(i))
            if now == (mode, armed, streams):
                continue
            self.faulted[i] = now
            change = {"mode": now[0]} if now[0] != mode else {}
            change |= {"armed": now[1]} if now[1] != armed else {}
            change |= {"position": "streaming" if now[2] else "stopped"} if now[2] != streams else {}
            reports.append({"uav": i, "boot_s": None, **change})
        for r in reports:
            i, boot_s = r.pop("uav"), r.pop("boot_s")
            t0 = self.t0_by_uav[i] if self.t0_by_uav is not None else self.t0
            t = (boot_s - t0) if boot_s is not None else (self.mission_t or 0)  # None: seen at this second
            entry = {"t": round(float(t), 2), "type": "autopilot", "uav": i, **r}
            log.info("autopilot fault report: %s", entry)
            if self.on_event is not None:
                self.on_event(entry)

    def _on_bus_connection(self, up: bool) -> None:
        """The world's broker connection broke or came back (a stalled or stopped broker, a
        scripted outage): recorded as `broker_lost` / `broker_back` at the mission second.
        The physics and telemetry do not wait for it; the agents fly on their predictions."""
        if self.mission_t is None or self.on_event is None or self._stop.is_set():
            return  # before the mission the start-up waits for the bus anyway; after it the broker is stopped on purpose
        entry = {"t": float(self.mission_t), "type": "broker_back" if up else "broker_lost"}
        log.warning("world: %s at t = %d s", "broker connection back" if up else "lost the broker connection", self.mission_t)
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
        self.tup_s = int(tup_s)
        self.ctl_seq += 1  # signed: agents apply only a ctl newer than the last (a replay is not)
        ctl = {"tup_s": self.tup_s, "seq": self.ctl_seq} if self.wire.signed else {"tup_s": self.tup_s}
        self._publish_retained(self.topics.ctl, self.wire.json("ctl", ctl))

    def stop(self) -> None:
        self._stop.set()

    async def shutdown(self, fleet: AgentFleet | None = None) -> None:
        """Stop the clock, close the vehicles' sockets and stop `fleet`'s agents (whatever
        state the run is in; safe to call twice)."""
        self.stop()
        self.vehicles.close()
        if fleet is not None:
            await fleet.stop()

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

    # ------------------------------------------------------------------ bus
    def _on_message(self, topic: str, payload: bytes) -> None:
        sender = self.topics.id_of(topic)
        counters = self.links.counters
        try:
            msg = self.wire.read_state(payload)
        except Malformed:
            counters.malformed += 1
            return
        except AuthError as exc:
            setattr(counters, exc.reason, getattr(counters, exc.reason) + 1)
            return
        if sender is None or not 0 <= sender < self.n:
            counters.malformed += 1
            return
        if msg.sender != sender:
            counters.misattributed += 1
            return
        if self.wire.signed and self.t0 is not None:
            now_t = self.now - self.t0
            if not now_t - self.tup_s - WINDOW_SLACK_S <= msg.t_s <= now_t + WINDOW_SLACK_S:
                counters.out_of_window += 1
                return
        if self.seq_filter.check(msg) is not None:
            counters.replayed += 1
            return
        if self.barrier is not None and msg.t_s > self._closed_upto:
            # Lockstep: relayed when the instant closes, in sender order (the loss draws too).
            self._held.setdefault(msg.t_s, {})[sender] = payload
            self._tx_wait_since = None  # progress: the wait for the rest restarts (`_instant_closed`)
            self.host.fleet.answers.set()  # type: ignore[union-attr]  # wake the barrier
            return
        pos = self.vehicles.positions()
        alive = self.alive()
        receivers = self.links.receivers(sender, pos, alive, self.now)  # decided at arrival
        if msg.t_s <= self._closed_upto:  # late for its instant: deliver it on its own
            for i in receivers:
                self._send_after_latency(self.topics.rx(i), payload)
            return
        batch = self._batches.setdefault(msg.t_s, {})
        for i in receivers:
            batch.setdefault(i, []).append(payload)
        heard = self._instants.setdefault(msg.t_s, set())
        heard.add(sender)
        if heard >= {i for i in range(self.n) if bool(alive[i])}:
            self._close_instant(msg.t_s)

    def _send_after_latency(self, topic: str, payload: bytes) -> None:
        if self.cfg.latency_s > 0:
            heapq.heappush(self._pending, (self.now + self.cfg.latency_s, next(self._tiebreak), topic, payload))
        else:
            self._publish_signal(topic, payload)

    def _publish_signal(self, topic: str, payload: bytes) -> None:
        if self.on_signal is not None:
            self.on_signal(topic, payload)
        self.bus.publish(topic, payload)

    def _close_instant(self, t_s: float) -> None:
        """Deliver instant t_s's updates, one rx message per receiver, then tell the agents
        that it has delivered all it will (through the same latency queue), so none waits
        out its timeout for a neighbour that is out of range. Without this marker (real
        radios) agents wait the timeout."""
        self._instants.pop(t_s, None)
        self._closed_upto = max(self._closed_upto, t_s)
        for i, payloads in sorted(self._batches.pop(t_s, {}).items()):
            self._send_after_latency(self.topics.rx(i), b"".join(payloads))
        self._send_after_latency(self.topics.closed, self.wire.json("closed", {"t_s": t_s}))

    def _close_overdue(self) -> None:
        """Close every open instant some updates are still missing from after half the
        agents' own wait bound (a vehicle whose agent died signals no more): the others'
        updates must reach them before they give up waiting."""
        if not self._instants or self.t0 is None:
            return
        now_t = self.now - self.t0
        wait = max(INSTANT_WAIT_MIN_S, 0.5 * INSTANT_WAIT_WALL_S * self.cfg.speedup)
        for t_s in [t for t in self._instants if now_t >= t + wait]:
            self._close_instant(t_s)

    def _deliver_due(self) -> None:
        while self._pending and self._pending[0][0] <= self.now:
            _, _, topic, payload = heapq.heappop(self._pending)
            if self._bus_cut:  # lockstep: an emulated outage swallows deliveries still under way
                self.links.counters.outage += 1
                continue
            self._publish_signal(topic, payload)

    # ------------------------------------------------------------------ per-second work
    def not_ready(self) -> list[str]:
        """Why the mission cannot start yet: one entry per vehicle not flying under its agent."""
        return self.vehicles.not_ready(self.takeoff_alt)

    def _ready(self) -> bool:
        return not self.not_ready()

    def _maybe_start(self, second: float) -> None:
        if self.t0 is not None:
            return
        if int(second) % WAIT_LOG_EVERY_S == 0:
            log.info("waiting for every vehicle to fly under its agent (armed, %s, at %.0f m%s): not yet %s",
                     "in the offboard mode" if self.host is not None else "in its offboard mode (ArduPilot GUIDED)",
                     self.takeoff_alt, "" if self.host is not None else ", climb over",
                     ", ".join(self.not_ready()) or "none")
        now = self.now
        if self._ready() or now >= self.cfg.start_timeout_s:
            if not self._ready():
                log.warning("start timeout: starting the mission with the vehicles that are ready")
                self.summary.not_ready_at_start = self.not_ready()
            margin = max(self.cfg.start_margin_s, self.cfg.start_margin_wall_s * self.cfg.speedup)
            self.t0 = float(math.ceil(now + margin))
            self.summary.t0_boot_s = self.t0
            self._next_second = self.t0
            self.t0_by_uav = self.vehicles.start_times(self.t0)
            start = {"t0_boot_s": self.t0, "tup_s": self.tup_s, "n_uavs": self.n}
            if self.t0_by_uav is not None:
                start["t0_boot_s_by_uav"] = self.t0_by_uav
            self.bus.publish(self.topics.start, self.wire.json("start", start), sticky=True)
            self._place_pending = self.barrier is not None
            self.publish_map(0, self.users)  # the users stay at their t = 0 positions until t0
            log.info("mission starts at boot %.0f s (now %.2f s)%s", self.t0, now,
                     f"; on each vehicle's clock {self.t0_by_uav}" if self.t0_by_uav is not None else "")

    def publish_map(self, k: int, users: UserState) -> None:
        """The user-density map of mission second k (users at k) on the retained demand topic."""
        m = self.mission
        counts = demand_map(users.xy[0], m.area.north_m, m.area.east_m, m.demand.cell_m)
        rows, cols = grid_shape(m.area.north_m, m.area.east_m, m.demand.cell_m)
        payload = self.wire.demand(self.map_seq, k * 1000, m.demand.cell_m, rows, cols, counts.round().long().tolist())
        self._publish_retained(self.topics.demand, payload)
        self.map_seq += 1

    def _step_users(self, k: int) -> None:
        """The users at mission second k (stepped earlier), and the seconds ahead up to one
        map period: a map instant among them has its map published now. One step per
        second, in order: the generator is used as in the twin."""
        m = self.mission
        if k >= 1:
            self.users = self.users_ahead.popleft()
        period = map_period(m.demand.refresh_s, m.timing.decision_every_s)
        while len(self.users_ahead) < period:
            last = self.users_ahead[-1] if self.users_ahead else self.users
            self.users_ahead.append(step_users(last, m, m.timing.dt_s, self.gen))
            t = k + len(self.users_ahead)
            if is_map_instant(t, m.demand.refresh_s, m.timing.decision_every_s):
                self.publish_map(t, self.users_ahead[-1])

    def _second(self, second: float) -> None:
        """Work at a whole second: mission second k = second - t0 (or a boot second before t0)."""
        m = self.mission
        k: int | None = None
        if self.t0 is not None and second >= self.t0 - 1e-6:
            k = int(round(second - self.t0))
            self._bus_cut = self._outage_emulated(k)
            if not self._bus_cut:
                for topic, payload in self._held_retained.items():
                    self.bus.publish(topic, payload, sticky=True)
                self._held_retained.clear()
            self._step_users(k)
            self.mission_t = k
        pos = self.positions()
        alive = self.alive()
        users = self.users.xy[0]  # (U, 2)
        cov = float(covered_users(users, pos, alive, self.radius(-pos[:, 2])).float().mean())
        rx, sinr = link_mask(pos, alive, m.channel, m.radii.comm_m)
        lam2 = float(algebraic_connectivity(weighted_adjacency(rx, sinr), alive))
        if k is not None and k >= 1:
            self.summary.coverage.append(cov)
            self.summary.lambda2.append(lam2)
        if k is not None and self.cfg.publish_sense and not self._bus_cut:
            t_ms = k * 1000
            r2 = m.radii.sensing_m**2
            for i in range(self.n):
                if not bool(alive[i]):
                    continue
                d = users - pos[i, :2]
                inside = users[(d * d).sum(-1) <= r2]
                self.bus.publish(self.topics.sense(i), self.wire.sense(i, t_ms, inside.tolist()))
        uav = self.vehicles.uav_rows()
        metrics = {
            "t": k,
            "boot_s": round(second, 3),
            "t0_boot_s": self.t0,
            "coverage": cov,
            "lambda2": lam2,
            "links_up": int(rx.sum()),
            "uav": uav,
            "link_counters": self.links.counters.as_dict(),
            "tup_s": self.tup_s,
        }
        self.bus.publish(self.topics.metrics, encode_json(metrics))
        if self.host is not None:
            self.host.log_counters()  # dropped MAVLink input (unsigned commands ...): a line when it moves
        if k is not None:
            self._report_faults(uav)
            self.apply_events(k)
        if self.on_metrics is not None:
            self.on_metrics(metrics)
        if k == 0:
            self._t0_wall = time.perf_counter()
        if k is not None and self.cfg.episode_s is not None and k >= self.cfg.episode_s:
            if self._t0_wall is not None:
                self.summary.mission_wall_s = time.perf_counter() - self._t0_wall
            self._stop.set()

    # ------------------------------------------------------------------ clock
    def _advance(self, sim_s: float) -> float:
        """Advance up to `sim_s` (stopping at the next whole second); returns what is left."""
        step = min(sim_s, CHUNK_S, self._next_second - self.now)
        if step > 1e-9:
            self.vehicles.advance(step)
            sim_s -= step
        if self.now >= self._next_second - 1e-9:
            self._at_second()
        return sim_s

    def _at_second(self) -> None:
        second = self._next_second
        self._second(second)
        self._next_second += 1.0
        self._maybe_start(second)

    async def _follow(self) -> None:
        """External vehicles: process each whole second once every live vehicle has reached
        it (their clocks, not ours), and the instants and the latency queue between."""
        assert isinstance(self.vehicles, ExternalVehicles)
        changed = self.vehicles.changed
        said = -math.inf
        joined = False
        log.info("waiting for the vehicles' telemetry on %s", self.vehicles.describe())
        while not self._stop.is_set():
            with contextlib.suppress(TimeoutError):
                async with asyncio.timeout(FOLLOW_POLL_S):
                    await changed.wait()
            changed.clear()
            now = self.now
            if not math.isfinite(now):
                if time.monotonic() - said >= 10.0:
                    said = time.monotonic()
                    log.info("no vehicle streams its position yet: %s", ", ".join(self.not_ready()))
                continue
            if not joined:  # the vehicles may have been running for a while: start from their second
                joined = True
                self._sim0 = now
                self._next_second = max(1.0, float(math.ceil(now)))
            while self._next_second <= now + 1e-9 and not self._stop.is_set():
                self._at_second()
                self._close_overdue()
                self._deliver_due()
            self._close_overdue()
            self._deliver_due()

    async def _clock(self) -> None:
        period = 1.0 / self.cfg.tick_hz
        catchup = CATCHUP_TICKS * period
        last = time.perf_counter()
        next_tick = last + period
        while not self._stop.is_set():
            delay = next_tick - time.perf_counter()
            await asyncio.sleep(max(0.0, delay))
            now = time.perf_counter()
            todo = min(now - last, catchup) * self.cfg.speedup  # bounded catch-up, as the runner
            if now - last > catchup and self._t0_wall is not None and self.t0 is not None:
                self._fell_behind(now - last - catchup, self.now - self.t0, now - self._t0_wall)
            last = now
            while todo > 1e-9 and not self._stop.is_set():
                todo = self._advance(todo)
                self._close_overdue()
                self._deliver_due()
                await asyncio.sleep(0)  # let datagrams and MQTT messages in between chunks
            next_tick = max(next_tick + period, now - period)

    def _fell_behind(self, lost_wall_s: float, mission_s: float, mission_wall_s: float) -> None:
        """The mission lost wall time to the bounded catch-up: say so once (`Pace`)."""
        self.pace.lose(lost_wall_s)
        msg = self.pace.notice(mission_s, mission_wall_s)
        if msg is not None:
            log.warning("%s", msg)
            if self.on_behind is not None:
                self.on_behind(msg)

    # ------------------------------------------------------------------ lockstep
    async def _lockstep_clock(self) -> None:
        """Lockstep: one physics substep at a time, each once the barrier is met (`_settle`).
        Until every live vehicle's agent has joined (start-up), also paced at wall x speedup:
        arming and take-off are wall-clock command exchanges and need vehicle time to pass."""
        assert self.host is not None and self.barrier is not None
        dt = self.host.physics_dt
        wall0, sim0 = time.perf_counter(), self.now
        next_tick = float(math.floor(self.now + 1e-9) + 1)
        joined = False
        while not self._stop.is_set():
            await self._settle()
            if self._stop.is_set():
                break
            if self._place_pending:  # every answer to the start second's telemetry is in
                self._place_pending = False
                self._place_at_start()
            self.vehicles.advance(dt)
            if self.now >= self._next_second - 1e-9:
                self._instant_tup = self.tup_s  # the instants of this second follow T_up before its events
                self._at_second()
            if self.now >= next_tick - 1e-9:  # every boot second, also those between the start and t0
                self._tick_due = next_tick
                next_tick += 1.0
            self._deliver_due()
            joined = joined or self.barrier.all_joined(self.alive().tolist())  # once all have joined, for good
            if joined:
                wall0, sim0 = time.perf_counter(), self.now
                await asyncio.sleep(0)
            else:
                await asyncio.sleep(max(0.0, (self.now - sim0) / self.cfg.speedup - (time.perf_counter() - wall0)))

    def _place_at_start(self) -> None:
        """The mission starts from the twin's start state exactly: every live vehicle at rest
        over its launch slot at the start altitude (the take-off before it ran on wall time)."""
        assert self.host is not None
        for i, a in enumerate(self.alive().tolist()):
            if a:
                self.host.place(i, (0.0, 0.0, -self.takeoff_alt))

    async def _settle(self) -> None:
        """The barrier: the tick of the last whole second is out (after its instant's states,
        relayed) and every member has answered its telemetry; stragglers are declared failed."""
        assert self.host is not None and self.barrier is not None
        b, wake = self.barrier, self.host.fleet.answers
        while not self._stop.is_set():
            wake.clear()
            wall = time.perf_counter()
            alive = self.alive().tolist()
            if self._tick_due is not None and self._instant_closed(alive, wall):
                self.bus.publish(self.topics.tick, self.wire.json("tick", {"boot_s": self._tick_due}), sticky=True)
                self._tick_due = None
                b.restart(wall)  # the answers held for this tick can come only now
            owing = b.owing(alive)
            late = b.overdue(owing, wall)
            if late:  # answers may be unread behind a stall of this process: read them first
                await asyncio.sleep(0)
                owing = b.owing(alive)
                late = b.overdue(owing, time.perf_counter())
            if late and self.agents_working is not None and self.agents_working(late):
                b.restart(time.perf_counter())  # still computing: a starved machine, not a straggler
                late = []
            for i in late:
                self.agent_failed(i, f"no answer to its telemetry for {b.straggler_s:g} s")
            if late:  # a failed agent owes nothing any more
                owing = b.owing(alive)
            if self._tick_due is None and not owing:
                return
            left = b.wait_left(owing, wall)
            if self._tick_due is not None:
                left = min(left, 0.5 * b.straggler_s)
            # Waiting only for answers: wake once the last of them is in, not at each one.
            self.host.fleet.awaited = set(owing) if self._tick_due is None else None
            try:
                with contextlib.suppress(TimeoutError):
                    async with asyncio.timeout(left):
                        await wake.wait()
            finally:
                self.host.fleet.awaited = None

    def _instant_closed(self, alive: list[bool], wall: float) -> bool:
        """The tick's second has no instant open: none is due, or every member's state for it
        is in (then relayed), or the broker is down, or it waited half the straggler bound."""
        assert self.barrier is not None and self._tick_due is not None
        if self.t0 is None or self._tick_due < self.t0 - 1e-6:
            return True
        k = float(round(self._tick_due - self.t0))
        if k % self._instant_tup != 0 and k not in self._held:
            return True
        missing = set(self.barrier.members(alive)) - set(self._held.get(k, {}))
        if missing and self.bus.connected.is_set():
            if self._tx_wait_since is None:
                self._tx_wait_since = wall
            if wall - self._tx_wait_since < 0.5 * self.barrier.straggler_s:
                return False
            log.warning("lockstep: instant %d closed without the states of %s", int(k), sorted(missing))
        self._tx_wait_since = None
        self._relay_instant(k)
        return True

    def _relay_instant(self, k: float) -> None:
        """Relay instant k's states in sender order, then close it (one rx per receiver, closed)."""
        held = self._held.pop(k, {})
        if self._outage_emulated(int(k)):
            self.links.counters.outage += len(held)
            held = {}
        pos, alive = self.vehicles.positions(), self.alive()
        batch = self._batches.setdefault(k, {})
        for sender in sorted(held):
            if self.on_signal is not None:
                self.on_signal(self.topics.tx(sender), held[sender])
            for i in self.links.receivers(sender, pos, alive, self.now):
                batch.setdefault(i, []).append(held[sender])
        self._close_instant(k)

    def agent_failed(self, i: int, why: str) -> None:
        """Agent i is gone (its process died, or in lockstep it stopped answering): recorded
        once; lockstep stops waiting for it. Its vehicle is left to its setpoint-loss failsafe."""
        if i in self.failed_agents:
            return
        self.failed_agents.add(i)
        if self.barrier is not None:
            self.barrier.fail(i, why)
        log.warning("agent %d declared failed (%s) at boot %.2f s; its vehicle is left to its failsafe", i, why, self.now)
        if self.on_agent_failed is not None:
            self.on_agent_failed(i, self.mission_t, why)
        if self.barrier is not None:
            self.host.fleet.answers.set()  # type: ignore[union-attr]

    # ------------------------------------------------------------------ lifecycle
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
        self._sim0 = self.now if self.vehicles.owns_clock else None  # external: once they are heard
        self.started_wall = t_wall
        try:
            async with asyncio.TaskGroup() as tg:
                bus = tg.create_task(self.bus.run(), name="world-bus")
                if self.barrier is not None:
                    await self._lockstep_clock()
                else:
                    await (self._clock() if self.vehicles.owns_clock else self._follow())
                await self._flush(1.0)
                bus.cancel()
        finally:
            torch.set_num_threads(threads)
            if not keep_sockets:
                self.vehicles.close()
            self.summary.wall_s = time.perf_counter() - t_wall
            self.summary.sim_s = self.now - self._sim0 if self._sim0 is not None else 0.0
            self.summary.links = self.links.counters.as_dict()
        return self.summary
