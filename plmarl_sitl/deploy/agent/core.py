"""The deployable agent: one asyncio process per UAV, next to its autopilot.

A composition of small parts, each with one job:

* `clock.MissionClock`: the mission clock, keyed to the VEHICLE clock
  (LOCAL_POSITION_NED.time_boot_ms), so a `--speedup` run behaves like a real-time one:
  signalling instants, when a second is due, when an instant's misses are booked;
* `inbox.Inbox`: bus payloads into the neighbour table, the clock and the sensing
  history, malformed ones counted by reason;
* `decision.Decision`: Algorithm 1 and the policy for one mission second, and the command;
* `session.VehicleSession`: MAVLink start-up, modes, setpoint stream, re-engage, stop;
* `stats`: loop timing, trace and the summary on exit.

The bus and the MAVLink link come from whoever starts the agent (`program`, or a test),
as the `Bus` and `session.Link` protocols. Flying, mission second k = boot_s - t0:

* at k (k % T_up == 0): publish the autopilot-reported state to tx/<id>;
* at the first telemetry of second k (at a signalling instant: once the updates of
  instant k have had time to arrive): close the signalling instant, advance the
  tracker one second, and every tau seconds run the policy, held until the next decision;
* every telemetry message (10 Hz of vehicle time, 5 Hz in lockstep) re-sends the current setpoint, with a
  wall-clock watchdog so the stream never stops while the process lives.

With `--lockstep` (SITL only, `lockstep.TickGate`) the setpoint carries the telemetry's
time_boot_ms, the first telemetry of each boot second is answered only once the world's
tick for that second is in, the wall-clock watchdog is off, and the clock decides on
ticks, not on wall-clock bounds (`MissionClock(lockstep=True)`).

A broker outage only stops updates: the tracker keeps predicting, the bus reconnects with
backoff. Stop (Ctrl-C/SIGTERM): hold (PX4 AUTO.LOITER) or brake (ArduPilot BRAKE), exit 0.
SIGUSR1 stops it too but leaves the vehicle to its autopilot (a SITL world took the UAV out
of the mission after an autopilot fault: no stop mode is commanded).
A failure ends the run the same way and is raised as itself (`errors.run_reporting` makes
it one line and an exit code).
"""

from __future__ import annotations

import asyncio
import logging
import time
from typing import Any, Protocol

import torch

from plmarl_sitl.deploy.agent.clock import MissionClock
from plmarl_sitl.deploy.agent.config import AgentConfig
from plmarl_sitl.deploy.agent.decision import Decision
from plmarl_sitl.deploy.agent.inbox import Inbox
from plmarl_sitl.deploy.agent.lockstep import TickGate
from plmarl_sitl.deploy.agent.neighbours import NeighbourTable
from plmarl_sitl.deploy.agent.session import Link, VehicleSession
from plmarl_sitl.deploy.agent.stats import LoopStats, Trace, process_start_time, write_stats
from plmarl_sitl.deploy.mqtt.schema import StateMsg, Topics
from plmarl_sitl.deploy.mqtt.wire import Wire
from plmarl_sitl.errors import reported
from plmarl_sitl.learning.nn.io import LoadedPolicy

log = logging.getLogger("plmarl.agent")

START_WAIT_LOG_S = 10.0  # wall: how often a wait for the SITL world's start is said again


class BusCounters(Protocol):
    def as_dict(self) -> dict[str, int]: ...


class Bus(Protocol):
    """The MQTT bus as the agent uses it (`mqtt.transport.MqttBus`). Its messages go to
    `Agent.inbox.on_message`; the agent only publishes and runs it."""

    @property
    def stats(self) -> BusCounters: ...
    def publish(self, topic: str, payload: bytes, *, retain: bool = False, sticky: bool = False) -> bool: ...
    async def run(self) -> None: ...


class Agent:
    def __init__(self, cfg: AgentConfig, lp: LoadedPolicy, bus: Bus, link: Link) -> None:
        self.cfg = cfg
        m = cfg.mission
        self.me, self.n = cfg.uav_id, m.n_uavs
        self.topics = Topics(cfg.swarm)
        self.bus = bus
        self.wire = Wire(cfg.swarm_key)
        self.seq = 0  # of this agent's state messages
        self.stats = LoopStats()
        self.t_proc0 = process_start_time()
        self.stop_event = asyncio.Event()
        self.stop_reason: str | None = None  # why it stopped (request_stop, a failure), for the log's last line
        self.trace = Trace(cfg.trace_path)
        self.clock = MissionClock(int(cfg.tup_s or m.signalling.tup_s), int(m.timing.decision_every_s),
                                  cfg.settle_min_s, cfg.settle_wall_s, lockstep=cfg.lockstep)
        self.table = NeighbourTable(self.n, self.me, m.signalling.drop_after_missed)
        self.decision = Decision(m, self.me, lp, self.clock, self.table, self.stats, self.trace, self.topics, cfg.lockstep,
                                 cfg.airframe_drag_per_s)
        # Lockstep SITL: a boot second's telemetry is answered once the world's tick for it is in.
        self.gate = TickGate() if cfg.lockstep else None
        self.inbox = Inbox(self.topics, self.me, self.n, self.table, self.clock, self.decision.sense_history,
                           self.decision.demand, wait_start=cfg.wait_start, wire=self.wire, on_tick=self.on_tick)
        self.session = VehicleSession(link, cfg, self.clock, self.decision, self.stats, self.t_proc0, self.on_telemetry)
        self.owed: tuple[Any, float, float] | None = None  # the telemetry not yet answered (lockstep), its t_in, c_in
        if self.gate is not None:
            bus.on_connection = self.on_bus_connection  # type: ignore[attr-defined]

    def on_telemetry(self, m: Any) -> None:
        """One LOCAL_POSITION_NED: advance the mission clock, publish the state due, then
        answer it (decide, send the setpoint) unless lockstep holds the answer for a tick."""
        t_in = time.perf_counter()
        c_in = time.thread_time()
        self.clock.observe(m.time_boot_ms / 1000.0, time.perf_counter())
        self.decision.observe(self.session.mission_state(m))
        if self.clock.t0 is not None:
            for k in self.clock.states_due(self.clock.mission_s()):
                self.publish_state(k)
        self.owed = (m, t_in, c_in)
        self._answer()

    def _answer(self) -> None:
        """Process the mission seconds now due and send the setpoint for the owed telemetry
        (stamped with its vehicle time in lockstep)."""
        if self.owed is None:
            return
        m, t_in, c_in = self.owed
        if self.gate is not None and self.session.flying and self.gate.holds(self.clock.boot_s):
            return  # the world's tick for this second answers it (on_tick)
        self.owed = None
        decided = False
        if self.clock.t0 is not None:
            decided = self.decision.catch_up(self.clock.mission_s())
        if self.session.flying:
            self.session.send_setpoint(m.time_boot_ms if self.gate is not None else 0)
        self.stats.tick(t_in, c_in, decided, getattr(m, "rx_ns", None), in_mission=self.clock.in_mission())

    def on_tick(self, boot_s: float) -> None:
        if self.gate is not None:
            self.gate.on_tick(boot_s)
            self._answer()

    def on_bus_connection(self, up: bool) -> None:
        """Lockstep: no tick can come while the broker is unreachable; answer without."""
        assert self.gate is not None
        self.gate.online = up
        if not up:
            self._answer()

    def publish_state(self, k: int) -> None:
        """This agent's state (the latest telemetry) for signalling instant k, to tx/<id>."""
        state = tuple(self.decision.ego_np.tolist())
        known = self.decision.table.knowledge.view(before=k)  # what it knew before the instant (model/gossip.py)
        msg = StateMsg.with_knowledge(self.me, self.cfg.session_id, self.seq, k * 1000, state, known)  # type: ignore[arg-type]
        self.seq += 1
        self.bus.publish(self.topics.tx(self.me), self.wire.state(msg))

    def request_stop(self, why: str) -> None:
        """Stop (the vehicle to its stop mode); `why` is said in the log's last line."""
        self.stop_reason = self.stop_reason or why
        self.stop_event.set()

    def release(self) -> None:
        """Stop without commanding the stop mode: the vehicle is left to its autopilot."""
        self.session.leave_to_autopilot = True
        self.request_stop("SIGUSR1: the vehicle is left to its autopilot")

    async def run(self) -> int:
        """Run until `stop_event` is set (signal handler): 0. A failure (the vehicle refuses,
        goes silent, is lost; a user error found on the way) is raised as itself, not in
        the task group's ExceptionGroup, after the vehicle is handed to its stop mode."""
        torch.set_num_threads(1)
        self.trace.open()
        try:
            async with asyncio.TaskGroup() as tg:
                helpers = [
                    tg.create_task(self.bus.run(), name="bus"),
                    tg.create_task(self.session.gcs_heartbeat(), name="gcs-heartbeat"),
                    tg.create_task(self._announce_start_wait(), name="start-wait"),
                ]
                if self.gate is None:  # lockstep: the world waits for the answers, a wall-clock re-send is noise
                    helpers.append(tg.create_task(self.session.watchdog(), name="setpoint-watchdog"))
                main = tg.create_task(self._main(), name="main")
                helpers.append(tg.create_task(self._cancel_on_stop(main), name="stop-watch"))
                # The helpers only serve `main`: when it ends, so do they.
                main.add_done_callback(lambda _t: [h.cancel() for h in helpers])
        except BaseExceptionGroup as eg:
            failure = reported(eg)
            self.stop_reason = f"{type(failure).__name__}: {failure}"
            raise failure from None
        finally:
            await self.session.hold()
            self.session.close()
            if self.trace.active:
                self.decision.track()  # the trace lines of the seconds since the last decision
            self.trace.close()
            self._write_stats()
            # The last line says why the agent stopped: a signal, a failure, or the flight's end.
            log.info("stopped (%s) after %d decisions", self.stop_reason or "the flight ended", self.stats.decisions)
        return 0

    async def _announce_start_wait(self) -> None:
        """Waiting for a SITL world's start announcement is said, every START_WAIT_LOG_S,
        with the way out for a real deployment (which has no world to announce it)."""
        topic = self.topics.start
        while True:
            if self.cfg.wait_start and self.session.flying and self.clock.t0 is None:
                log.info("waiting for the SITL world's start message on %s (a real deployment has no SITL world: "
                         "run the agents with --bus direct)", topic)
            await asyncio.sleep(START_WAIT_LOG_S)

    async def _cancel_on_stop(self, main: asyncio.Task) -> None:
        await self.stop_event.wait()
        main.cancel()

    async def _main(self) -> None:
        try:
            self.decision.warm_up()
            await self.session.start()
            if not self.cfg.wait_start and self.clock.t0 is None:
                epoch = await self.session.common_epoch()
                # A midnight lies before the vehicle booted (t0 < 0: hours of mission seconds
                # already past); every agent of the swarm picks the same one, so they agree.
                self.clock.set_t0(epoch, "the vehicle's boot" if epoch == 0.0 else
                                  "the last UTC midnight, the swarm's common epoch in direct mode")
            await self.session.fly(self.stop_event)
        except asyncio.CancelledError:
            if not self.stop_event.is_set():
                raise  # cancelled from outside: propagate; a requested stop ends quietly

    def _write_stats(self) -> None:
        if self.cfg.stats_path is None:
            return
        write_stats(self.cfg.stats_path, self.stats, {
            "rx": self.inbox.rx.as_dict(),
            "bus": self.bus.stats.as_dict(),
            "dropped": self.table.dropped,
            "reengaged": self.session.reengaged,
            "fail": self.table.lost,  # a neighbour was dropped (input version 1's flag)
            "f": self.decision.fail,  # the flag the policy got at the last decision
            "demand": self.decision.demand.counters(),
        })
