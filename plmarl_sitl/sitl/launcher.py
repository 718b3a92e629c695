"""`plmarl swarm up`: a whole SITL swarm from one command.

This process starts the broker (amqtt in a child process, unless an external one is
given; behind a `BrokerGate` when the mission has a broker outage) and hosts the SITL
world (`SitlWorld`: autopilots, users, link emulator); it forks one `plmarl agent` per
UAV (`sitl.forked`) and watches them. With `--hosts HOSTS.yaml` the agents of the UAVs a host
lists run on that host instead (`sitl.hosts`, `sitl.remote`), reached through its command
prefix (ssh); the broker and the vehicles' ports then listen on the launcher's address
from the hosts file, and a host that falls silent is recorded as node failures. With `--autopilot arducopter=PATH` the autopilots
are real: one ArduCopter SITL process per UAV (`sitl.arducopter`), each agent on its
SERIAL0, the world following each vehicle on its SERIAL1 (`sitl.external`); with `--autopilot px4=PATH`
one PX4 SITL (SIH) process per UAV (`sitl.px4`), each agent on its offboard link, the world on its
GCS link. The world starts mission time once every vehicle
flies under its agent; the mission's events fire on that clock, from one schedule
(`model.events`): the world applies those in its own process, the launcher those that
touch the processes it manages (`LauncherEvents`: agent kills, the broker gate).
Everything is recorded in the run directory:

    mission.yaml      the resolved mission (extends applied, seed filled in)
    metrics.jsonl     one row per mission second: t, coverage, lambda2, messages, uavs
    metrics.csv       the same, one wide row per second (columns: sitl/report_csv.py)
    events.jsonl      every event as it fired; autopilot faults also what the vehicle then
                      said and did ("autopilot" entries) and when it left the mission ("uav_failed")
    summary.json      coverage mean/min, duration, speedup, events, node-failure recovery
    tlogs/vehicleI.tlog   each vehicle's MAVLink traffic (pymavlink / MAVExplorer; ArduCopter:
                      the world's SERIAL1 link, both ways)
    arducopter/vehicleI/  ArduCopter's working directory: arducopter.log, plmarl.parm, logs/
    px4/vehicleI/         PX4's working directory: px4.log, parameters, dataman
    agents/agentI.log     each agent's log (and its P-AoI trace); a remote agent's comes back over its host's link
    hosts/NAME.stderr     with --hosts: what each host's command prefix (ssh) said
    launcher.log      world, bus and launcher log

Shutdown (mission end, Ctrl-C, SIGTERM or a failed component) stops the agents (SIGTERM,
then SIGKILL), the world, the ArduCopters or PX4s and the broker, so no process is left behind.
"""

from __future__ import annotations

import asyncio
import contextlib
import datetime as _dt
import gc
import json
import logging
import math
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import yaml

from plmarl_sitl.config import to_dict
from plmarl_sitl.deploy.mavlink.keys import create_key_files, key_file
from plmarl_sitl.deploy.mqtt.auth import SwarmKey, create_key_file
from plmarl_sitl.deploy.mqtt.transport import MqttBus
from plmarl_sitl.deploy.mqtt.url import parse_broker_url
from plmarl_sitl.deploy.mqtt.wire import Wire
from plmarl_sitl.errors import PlmarlError
from plmarl_sitl.mission import Event, Mission
from plmarl_sitl.model.events import Change
from plmarl_sitl.sitl.agents import SITL_AGENT_NICE, AgentFleet
from plmarl_sitl.sitl.arducopter import ArduCopterFleet
from plmarl_sitl.sitl.forked import start_server
from plmarl_sitl.sitl.hosts import Host
from plmarl_sitl.sitl.live import headless_line, render
from plmarl_sitl.sitl.mission_events import EventDispatcher
from plmarl_sitl.sitl.monitor import SwarmMonitor
from plmarl_sitl.sitl.network.access import BrokerAccess
from plmarl_sitl.sitl.network.broker import AmqttProcess, MosquittoBroker, free_udp_ports
from plmarl_sitl.sitl.network.broker_gate import BrokerGate
from plmarl_sitl.sitl.options import OWN_BROKERS, UpOptions, swarm_options
from plmarl_sitl.sitl.px4 import SIGNING_UNSUPPORTED, SIH_DRAG_PER_S, Px4Fleet
from plmarl_sitl.sitl.remote import HostFailed, RemoteHosts
from plmarl_sitl.sitl.report_csv import write_metrics_csv
from plmarl_sitl.sitl.run_inputs import RunInputs, load_inputs
from plmarl_sitl.sitl.rundir import claim_run_dir
from plmarl_sitl.sitl.summary import summarize, timeliness
from plmarl_sitl.sitl.world import SitlWorld, WorldConfig

log = logging.getLogger("plmarl.swarm")

class ComponentFailed(PlmarlError):
    """A part of the running swarm died or could not start; `reason` is one line."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


WAITING_EVERY_S = 10  # vehicle s between `--headless` start-up lines, as between its mission lines
WAITING_SHOWN = 4  # vehicles named in such a line


def default_out_dir() -> Path:
    return Path("runs") / _dt.datetime.now().strftime("%Y-%m-%dT%H-%M-%S")


class LauncherEvents:
    """The launcher's part of the mission's events, registered on the world's dispatcher
    (`mission_events.EventDispatcher`; the world registers the vehicle, the links, GNSS
    noise, T_up and autopilot faults): it kills a failed node's agent process, asks the
    agent of a UAV an autopilot fault took out of the mission to stop (its companion
    computer lives on), opens and closes the broker gate for an outage, and records every
    event as it fires."""

    # The ends worth an entry of their own: the outage's, the noise's and the GPS's are
    # switched at their end second; a blackout's cut expires inside the link emulator.
    RECORDED_ENDS = frozenset({"broker_outage", "gnss_noise", "gps_loss"})

    def __init__(self, events: EventDispatcher, fleet: AgentFleet, gate: BrokerGate | None, record: Callable[[dict], None]) -> None:
        self.schedule, self.fleet, self.gate, self.record = events.schedule, fleet, gate, record
        self.killed: set[int] = set()  # agents stopped on purpose (not a failure to report)
        events.on("node_failure", self._on_node_failure)
        events.on("broker_outage", self._on_broker_outage)
        events.on_every(self._record)
        events.on_fault_failure(self._on_fault_failure)

    def _on_node_failure(self, change: Change) -> None:
        uav = change.event.uav
        if uav is not None:
            self.killed.add(uav)
            if uav in self.fleet.procs:
                self.fleet.kill(uav)

    def _on_broker_outage(self, change: Change) -> None:
        if self.gate is not None and self.schedule is not None:  # lockstep: no gate, the world emulates it
            self.gate.outage(self.schedule.broker_down(change.second))  # down while any outage lasts

    def _record(self, change: Change) -> None:
        ev, t = change.event, float(change.second)
        if not change.ends:
            entry = {"t": t, "type": ev.type,
                     **{k: v for k, v in to_dict(ev).items() if k not in ("type", "at_s") and v not in (None, [])}}
            log.warning("event at t=%.0f s: %s", t, entry)
            self.record(entry)
        elif ev.type in self.RECORDED_ENDS:
            self.record({"t": t, "type": f"{ev.type}_end"})

    def _on_fault_failure(self, uav: int, ev: Event, second: int) -> None:
        self.killed.add(uav)
        if uav in self.fleet.procs:
            self.fleet.retire(uav)
        entry = {"t": float(second), "type": "uav_failed", "uav": uav, "cause": ev.type}
        log.warning("event at t=%.0f s: %s", second, entry)
        self.record(entry)


# What each broker we start guarantees, said in one line at start (docs/SECURITY.md).
BROKER_GUARANTEES = {
    "mosquitto": "mosquitto: a login per process (password file), ACL (agent i publishes only tx/i and reads only "
                 "what is addressed to it; the world its topics; the view reads), login = client id",
    "embedded": "embedded amqtt: a login per process and topic ACLs (publish, subscribe) are enforced; it cannot bind "
                "a login to its client id (a valid login can take over another client's session: a denial of "
                "service, not an impersonation) and has no TLS; use --broker mosquitto for that",
}


async def _start_broker(spec: str, access: BrokerAccess | None, out: Path, bind: str = "127.0.0.1",
                        port: int = 0) -> tuple[AmqttProcess | MosquittoBroker | None, str, int]:
    if spec in ("embedded", "mosquitto"):
        broker = (AmqttProcess(bind, port, access=access) if spec == "embedded"
                  else MosquittoBroker(bind, port, access=access))
        try:
            await asyncio.to_thread(broker.start, 20.0, out)  # amqtt imports and hashes passwords first
        except (RuntimeError, TimeoutError, OSError, subprocess.CalledProcessError) as exc:
            raise ComponentFailed(f"the {broker.what} broker did not start: {exc}") from exc
        return broker, broker.host, broker.port
    host, port = parse_broker_url(spec)  # UserError on a malformed URL
    try:
        async with asyncio.timeout(3):
            _, w = await asyncio.open_connection(host, port)
            w.close()
    except (OSError, TimeoutError) as exc:
        raise ComponentFailed(f"cannot reach the broker at {spec} ({exc.__class__.__name__})") from exc
    return None, host, port


def _swarm_key(opts: UpOptions, out: Path, given: SwarmKey | None) -> tuple[Path | None, SwarmKey | None]:
    """The run's key file and key: the one given (loaded by `load_inputs`), else a fresh one
    in the run directory."""
    if not opts.auth:
        log.warning("--no-auth: the swarm's messages are unsigned")
        return None, None
    if opts.swarm_key is not None:
        return opts.swarm_key, given
    path = out / "swarm.key"
    return path, create_key_file(path)


def _mavlink_keys(opts: UpOptions, out: Path, n: int, given: list[bytes] | None) -> tuple[Path | None, list[bytes]]:
    """The directory of the vehicles' MAVLink keys and the keys: the ones given (loaded by
    `load_inputs`), else fresh ones in RUN_DIR/mavlink; (None, []) for unsigned links."""
    if not opts.mavlink_sign:
        log.warning("--no-mavlink-sign: the MAVLink links are unsigned")
        return None, []
    if opts.mavlink_keys is not None and given is not None:
        return opts.mavlink_keys, given
    return out / "mavlink", create_key_files(out / "mavlink", n)


def _setup_logging(out: Path) -> logging.Handler:
    handler = logging.FileHandler(out / "launcher.log")
    handler.setFormatter(logging.Formatter("%(asctime)s %(name)s %(levelname)s %(message)s"))
    root = logging.getLogger()
    root.addHandler(handler)
    root.setLevel(logging.INFO)
    for name in ("amqtt", "transitions", "aiomqtt"):
        logging.getLogger(name).setLevel(logging.WARNING)
    return handler


async def swarm_up(opts: UpOptions, console=None, mission: Mission | None = None) -> dict:  # noqa: ANN001 - rich Console
    """Run a mission end to end; returns the summary. Raises ComponentFailed/UserError.

    Start-up is one async exit stack: each part, once created, registers how it stops, so
    the mission's end, Ctrl-C, SIGTERM or a failed component stop them in reverse order:
    the agents first (while the vehicles still answer, each commands hold and exits), then
    the world, the ArduCopters, the remote hosts, the gate, the broker, the run's files."""
    from rich.console import Console

    console = console or Console()
    inputs = load_inputs(opts, mission)
    mission = inputs.mission
    if inputs.size_warning is not None:
        console.print(f"[yellow]warning:[/] {inputs.size_warning}", highlight=False)
    out = opts.out or default_out_dir()
    run_lock = claim_run_dir(out)  # noqa: F841 - held by this frame until the run ends (sitl/rundir.py)
    run = _Run(opts, inputs, out, console)
    async with contextlib.AsyncExitStack() as stack:
        try:
            await run.start_and_fly(stack)
        except* ComponentFailed as group:
            raise group.exceptions[0] from None
    world = run.world
    if not run.rows:
        raise ComponentFailed(f"the mission never started (see {out / 'launcher.log'})")
    summary = summarize(run.rows, run.events, opts.speedup)
    t0s = world.t0_by_uav if world is not None and world.t0_by_uav is not None else world.t0 if world else None
    traces = [ap.trace() for ap in run.fleet.procs.values()]
    summary["timeliness"] = timeliness(traces, [t0s[i] for i in run.fleet.procs] if isinstance(t0s, list) else t0s)
    summary["autopilot"] = opts.autopilot if run.real else f"emulator ({opts.personality})"
    summary["mavlink_signed"] = bool(run.mav_keys)
    if world is not None and world.host is not None:  # what each emulated vehicle dropped, by reason
        summary["vehicle_input"] = [c.drops() for c in world.host.counters()]
    summary["run_dir"] = str(out)
    summary["seed"] = mission.seed
    summary["policy"] = str(opts.policy)  # what `plmarl report` flies in the twin for its reference line
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    write_metrics_csv(out / "metrics.csv", run.rows)
    # Wall-clock figures go to the caller only: summary.json stays identical between
    # lockstep runs of one seed.
    mission_wall = world.summary.mission_wall_s if world is not None else None
    return {**summary, "mission_wall_s": mission_wall,
            "achieved_speedup": summary["duration_s"] / mission_wall if mission_wall else None}


class _Run:
    """One `swarm up` run: its parts as they start, and what it records."""

    def __init__(self, opts: UpOptions, inputs: RunInputs, out: Path, console) -> None:  # noqa: ANN001 - rich Console
        self.opts, self.inputs, self.out, self.console = opts, inputs, out, console
        self.real = opts.autopilot != "emulator"
        self.n = inputs.mission.n_uavs
        self.duration = opts.duration_s or inputs.mission.timing.episode_s
        self.events: list[dict] = []
        self.rows: list[dict] = []
        self.world: SitlWorld | None = None
        self.mav_keys: list[bytes] = []
        self._last_headless = -10.0

    def record_event(self, entry: dict) -> None:
        self.events.append(entry)
        self.events_f.write(json.dumps(entry) + "\n")
        self.events_f.flush()
        if entry["type"] != "autopilot":  # the vehicle's own reports stay in the recording
            self.monitor.on_event(entry)

    def on_metrics(self, m: dict) -> None:
        self.monitor.on_metrics(m)
        if m.get("t") is None:
            return
        row = self.monitor.metrics_row()
        if row is not None:
            self.rows.append(row)
            self.metrics_f.write(json.dumps(row) + "\n")
            self.metrics_f.flush()
        if self.opts.headless and m["t"] >= self._last_headless + 10:
            self._last_headless = float(m["t"])
            self.console.print(headless_line(self.monitor.view()), highlight=False)

    def say_waiting(self, second: float, not_ready: list[str], takeoff_alt: float) -> None:
        """`--headless` before the start, every WAITING_EVERY_S vehicle seconds: what start-up waits for."""
        if int(second) % WAITING_EVERY_S or not not_ready:
            return
        shown = ", ".join(not_ready[:WAITING_SHOWN]) + (f", +{len(not_ready) - WAITING_SHOWN} more" if len(not_ready) > WAITING_SHOWN else "")
        self.console.print(f"start-up, {second:.0f} s: waiting for {len(not_ready)} of {self.n} vehicles to fly under their agents "
                           f"(armed, offboard, at {takeoff_alt:.0f} m): {shown}", highlight=False)

    async def start_and_fly(self, stack: contextlib.AsyncExitStack) -> None:
        from rich.live import Live

        opts, inputs, out, console, n = self.opts, self.inputs, self.out, self.console, self.n
        mission, schedule, hosts, real, duration = inputs.mission, inputs.schedule, inputs.hosts, self.real, self.duration
        bind = hosts.launcher.address if hosts is not None else "127.0.0.1"
        stack.callback(_teardown_logging, _setup_logging(out))
        mission_file = out / "mission.yaml"
        mission_file.write_text(yaml.safe_dump(to_dict(mission), sort_keys=False))
        key_path, key = _swarm_key(opts, out, inputs.swarm_key)
        if opts.autopilot == "px4" and opts.mavlink_sign:
            log.warning("%s", SIGNING_UNSUPPORTED)
            console.print(f"[bold yellow]{SIGNING_UNSUPPORTED}[/]", highlight=False)
            self.opts = opts = replace(opts, mavlink_sign=False)
        mav_dir, self.mav_keys = _mavlink_keys(opts, out, n, inputs.mavlink_keys)
        mav_keys = self.mav_keys
        self.metrics_f = stack.enter_context(open(out / "metrics.jsonl", "w"))  # noqa: SIM115 - closed by the stack
        self.events_f = stack.enter_context(open(out / "events.jsonl", "w"))  # noqa: SIM115
        self.monitor = monitor = SwarmMonitor(opts.swarm, mission.signalling.tup_s, mission.signalling.drop_after_missed,
                                              opts.speedup, Wire(key), mission=None if opts.headless else mission)  # the live view's map
        autopilots = {"arducopter": f"ArduCopter SITL {opts.arducopter}", "px4": f"PX4 SITL (SIH) {opts.px4}"}.get(
            opts.autopilot, f"emulated {opts.personality}")
        pace = (f"lockstep (start-up at {opts.speedup:g}x; an agent that owes an answer for {opts.straggler_s:g} s wall is "
                "declared failed)" if opts.lockstep else f"at {opts.speedup:g}x")
        console.print(f"[bold]plmarl swarm up[/] {opts.mission_path}: {n} UAVs ({autopilots}), {duration} s {pace}, "
                      f"seed {mission.seed}, policy {opts.policy}, broker {opts.broker}; recording to {out}")
        # The security set-up is said in full under -v (and always in launcher.log); what is
        # unprotected is said always.
        if key is None or opts.verbose:
            console.print(f"messages signed with the swarm key {key_path}" if key is not None else
                          "[bold red]--no-auth[/]: messages are unsigned; anyone who can publish on the broker can steer the swarm",
                          highlight=False)
        if (mav_dir is None and opts.autopilot != "px4") or opts.verbose:  # px4: said above
            console.print(f"MAVLink signed: vehicle i and its agent share {mav_dir}/vehicleI.key" if mav_dir is not None else
                          "[bold red]--no-mavlink-sign[/]: MAVLink links are unsigned; anyone who reaches an autopilot's port can "
                          "command it", highlight=False)
        t_launch = time.monotonic()  # start-up's steps are logged from here (launcher.log)
        remote = RemoteHosts(hosts, out / "hosts") if hosts is not None else None
        self.fleet = fleet = AgentFleet(out / "agents", forked=True, nice=SITL_AGENT_NICE,
                                        remote=remote.placement if remote else {})
        if len(fleet.remote) < n:
            fleet.warm_up(opts.policy, mission_file)  # the agents' imports and policy load on the other core meanwhile
            server = start_server()  # running already: `plmarl swarm up` forked it first thing (cli/swarm.py)
            log.info("start-up: the agents' fork server, pid %d, %s", server.pid, server.how)
        # Our own broker: a login per process and an ACL; an external one: its own business.
        access = BrokerAccess(opts.swarm, n) if opts.broker in OWN_BROKERS else None
        if access is not None:
            creds = access.write_credentials(out / "credentials")
            world_login, monitor_login = access["world"].credentials, access["monitor"].credentials
        else:
            creds = inputs.login_files
            world_login, monitor_login = inputs.logins.get("world"), inputs.logins.get("monitor")
        broker, up_host, up_port = await _start_broker(opts.broker, access, out, bind,
                                                       (hosts.launcher.broker_port or 0) if hosts is not None else 0)
        if broker is not None:
            stack.push_async_callback(asyncio.to_thread, broker.stop)
        guarantees = BROKER_GUARANTEES.get(opts.broker, f"external broker {opts.broker}: its access control is its own "
                                           "(docs/SECURITY.md has the ACL to give it)")
        if opts.verbose or access is None:  # an external broker's protection is its own: always said
            console.print(guarantees + (f"; logins in {out / 'credentials'}" if access is not None else ""), highlight=False)
        log.info("%s; swarm key %s; MAVLink keys %s", guarantees, key_path, mav_dir)
        # Every byte through the gate costs this process's event loop two hops, which at
        # N = 20 and 15x delays signalling; only a free-running mission with a broker outage
        # needs it (a lockstep world emulates the outage: `sitl.outbox`).
        gate = BrokerGate(up_host, up_port, host=bind) if schedule.has("broker_outage") and not opts.lockstep else None
        bus_url = f"mqtt://{up_host}:{up_port}"
        if gate is not None:
            stack.push_async_callback(gate.close)
            await gate.start()
            bus_url = gate.url
        if remote is not None:  # every host's companion reaches the broker before any agent starts
            stack.push_async_callback(remote.close)
            try:
                for line in await remote.connect(bus_url):
                    console.print(line, highlight=False)
                    log.info("%s", line)
            except HostFailed as exc:
                raise ComponentFailed(str(exc)) from None
        copters: ArduCopterFleet | Px4Fleet | None = None
        start_timeout_s = None  # the world's own vehicle-second bound (WorldConfig's default)
        if opts.autopilot == "px4":
            assert opts.px4 is not None
            copters = Px4Fleet(opts.px4, mission, opts.speedup, out, opts.instance_base)
            stack.push_async_callback(copters.stop)
            copters.start()
            for line in filter(None, (copters.ports_line(), copters.gcs_warning())):
                console.print(line, highlight=False)
                log.info("%s", line)
            try:
                await copters.wait_listening()
            except RuntimeError as exc:
                raise ComponentFailed(str(exc)) from exc
            await copters.quiet_gcs_links()
            agent_urls = copters.agent_urls()
            external = tuple(copters.world_urls())
            base_port = WorldConfig.base_port  # the vehicles fly elsewhere: no ports of the world's own
            # A PX4's clock runs from its own start, not from its agent's connection (ArduCopter's
            # does): with slow agent forks at --speedup 2 it passed the world's 300 vehicle-second
            # start timeout before any agent had connected, and the mission started on the ground.
            # The launcher's wall-clock start timeout (`_watch`) decides instead.
            start_timeout_s = math.inf
        elif real:
            assert opts.arducopter is not None and inputs.copter_parm is not None
            copters = ArduCopterFleet(opts.arducopter, inputs.copter_parm, mission, opts.speedup, out, opts.instance_base)
            stack.push_async_callback(copters.stop)
            copters.start()
            console.print(copters.ports_line(), highlight=False)
            log.info("%s", copters.ports_line())
            try:
                await copters.wait_listening()
                if mav_keys:
                    await copters.provision_signing(mav_keys)
            except RuntimeError as exc:
                raise ComponentFailed(str(exc)) from exc
            agent_urls = [f"tcpout://127.0.0.1:{p.serial0}" for p in copters.procs]
            external = tuple(f"tcpout://127.0.0.1:{p.serial1}" for p in copters.procs)
            base_port = WorldConfig.base_port  # the vehicles fly elsewhere: no ports of the world's own
        else:
            base_port = (hosts.launcher.vehicle_base_port if hosts is not None else None) or free_udp_ports(n, bind)
            agent_urls = [f"udpout://{bind}:{base_port + i}" for i in range(n)]
            external = ()
        cfg = WorldConfig(mission, bus_url, **swarm_options(opts), base_port=base_port, bind_host=bind,
                          episode_s=duration, events=schedule, external=external,
                          swarm_key=key, broker_credentials=world_login, mavlink_keys=tuple(mav_keys),
                          **({} if start_timeout_s is None else {"start_timeout_s": start_timeout_s}))
        self.world = world = SitlWorld(cfg, on_metrics=self.on_metrics, on_event=self.record_event)
        stack.callback(_close_world, world)
        world.on_behind = lambda msg: console.print(f"[yellow]world:[/] {msg}", highlight=False)
        if opts.headless:  # the live view shows each vehicle's state itself
            world.on_waiting = lambda second, not_ready: self.say_waiting(second, not_ready, world.takeoff_alt)
        script = LauncherEvents(world.events, fleet, gate, self.record_event)  # registers its handlers on the world's dispatcher
        world.vehicles.record_tlogs(out / "tlogs")
        await world.start()
        log.info("start-up: world started at %.1f s", time.monotonic() - t_launch)
        observer = None
        if opts.lockstep:
            # The world hands the monitor each state as it relays it and each delivery as it
            # sends it, in its own order: overheard on the broker they would race the metrics.
            world.relay.on_signal = monitor.on_bus
        # An agent that dies is a node failure to record, in both paces, not a lost run.
        world.on_agent_failed = lambda i, k, why: _agent_failed(fleet, script, self.record_event, i, k, why)
        world.agents_working = fleet.working
        if not opts.lockstep:
            observer = MqttBus(bus_url, f"plmarl-launcher-{opts.swarm}", [monitor.topics.tx("+"), monitor.topics.rx("+")],
                               monitor.on_bus, name="launcher-bus", credentials=monitor_login)
        # Agents stop first, while the vehicles still answer: each commands hold and exits.
        stack.push_async_callback(fleet.stop)
        # All at once: one by one, each fork waited for the forkserver and this loop to be
        # scheduled in turn (100 agents: 22-34 s on a loaded 2-core machine).
        await asyncio.gather(*(
            fleet.spawn(i, agent_urls[i], bus_url, mission=mission_file, policy=opts.policy, swarm=opts.swarm,
                        extra=["--autopilot", {"arducopter": "ardupilot", "px4": "px4"}.get(opts.autopilot, opts.personality),
                               *(["--lockstep"] if opts.lockstep else []),
                               *(["--airframe-drag", str(SIH_DRAG_PER_S)] if opts.autopilot == "px4" else [])],
                        verbose=opts.verbose,
                        swarm_key=key_path, credentials=creds.get(f"agent{i}"),
                        mavlink_key=key_file(mav_dir, i) if mav_dir is not None else None)
            for i in range(n)))
        log.info("start-up: %d agents forked at %.1f s", n, time.monotonic() - t_launch)
        # What start-up built in this process (torch, the model, the mission, the world, the
        # agents' handles: ~2e5 objects) lives for the whole run: frozen, the collector's full
        # passes no longer walk it (in a scale_20 run two or three in the mission, ~0.2 s of CPU
        # each). Not collected first: that is one such pass, for a few hundred garbage objects.
        gc.freeze()
        async with asyncio.TaskGroup() as tg:
            world_task = tg.create_task(world.run(keep_sockets=True), name="world")
            bus_task = None if observer is None else tg.create_task(observer.run(), name="launcher-bus")
            watch = tg.create_task(_watch(fleet, script, world, opts.start_timeout(), copters, remote), name="watchdog")
            view = None if opts.headless else tg.create_task(_live(Live, console, monitor, world_task), name="live-view")
            await world_task
            for t in (bus_task, watch, view):
                if t is not None:
                    t.cancel()


def _close_world(world: SitlWorld) -> None:
    world.stop()
    world.vehicles.close()


def _teardown_logging(handler: logging.Handler) -> None:
    logging.getLogger().removeHandler(handler)
    handler.close()


async def _watch(fleet: AgentFleet, script: LauncherEvents, world: SitlWorld, start_timeout_s: float,
                 copters: ArduCopterFleet | Px4Fleet | None = None, remote: RemoteHosts | None = None) -> None:
    """Fail fast, with a one-line reason, when an agent or an ArduCopter or PX4 dies unasked or
    nothing takes off; a host gone silent in the mission is node failures, not a failure of the run."""
    loop = asyncio.get_running_loop()
    t_start = loop.time()
    while True:
        await asyncio.sleep(0.5)
        gone = copters.exited() if copters is not None else None
        if gone is not None:
            raise ComponentFailed(gone.exit_reason())
        if remote is not None and world.t0 is not None and world.host is not None:
            heard = [c.datagrams for c in world.host.counters()]
            for host in remote.lost(heard, script.killed | world.failed_agents, loop.time()):
                _host_lost(host, fleet, script, world, remote.file.silence_s)
        for i, ap in list(fleet.procs.items()):
            rc = ap.proc.returncode
            if rc is None or i in script.killed:
                continue
            tail = ([ln for ln in ap.log().splitlines() if ln.strip()][-1:] or ["(empty log)"])[0][-160:]
            if not world.lockstep and world.t0 is None:  # free-running, before the mission: a start-up failure
                raise ComponentFailed(f"agent {i} exited with code {rc} before the mission started: {tail} (log: {ap.log_path})")
            # In flight (or in lockstep): the mission goes on without it, its vehicle to its failsafe.
            world.agent_failed(i, f"exited with code {rc}" + (f" ({tail})" if rc not in (-9, 137) else " (killed)"))
        if world.t0 is None and loop.time() - t_start > start_timeout_s:
            waiting = "; ".join(world.not_ready()) or "?"
            raise ComponentFailed(f"vehicles not airborne after {start_timeout_s:.0f} s: {waiting}")


def _agent_failed(fleet: AgentFleet, script: LauncherEvents | None, record: Callable[[dict], None], i: int,
                  k: int | None, why: str) -> None:
    """Lockstep: the world declared agent i failed. Its process is killed (a stopped or hung
    agent must not come back and fly) and its vehicle is left to its setpoint-loss failsafe."""
    if script is not None:
        script.killed.add(i)
    if i in fleet.procs:
        fleet.kill(i)
    record({"t": float(k) if k is not None else -1.0, "type": "agent_failed", "uav": i, "why": why})


def _host_lost(host: Host, fleet: AgentFleet, script: LauncherEvents, world: SitlWorld, silence_s: float) -> None:
    """A host none of whose agents has been heard for silence_s (its link is down, it lost
    power): each of its UAVs still in the mission is a node failure. The world takes the UAV
    out of the mission (its vehicle flies on under its setpoint-loss failsafe) and, in
    lockstep, stops waiting for its agent; the agent is killed, should its host come back."""
    t = float(world.mission_t or 0)
    for u in host.uavs:
        if u in script.killed:
            continue
        script.killed.add(u)
        world.vehicles.mark_failed(u)
        entry = {"t": t, "type": "node_failure", "uav": u, "cause": "host_lost", "host": host.name}
        log.warning("host %s silent for %g s: %s", host.name, silence_s, entry)
        script.record(entry)
        if world.lockstep:
            world.agent_failed(u, f"host {host.name} lost")
        if u in fleet.procs:
            fleet.kill(u)


async def _live(live_cls, console, monitor: SwarmMonitor, world_task: asyncio.Task) -> None:  # noqa: ANN001
    with live_cls(render(monitor.view()), console=console, refresh_per_second=4, transient=False) as live:
        while not world_task.done():
            live.update(render(monitor.view()))
            await asyncio.sleep(0.25)
        live.update(render(monitor.view()))


def run_up(opts: UpOptions, mission: Mission | None = None) -> dict:
    """Run `swarm_up` in a fresh event loop; SIGINT (Ctrl-C) and SIGTERM stop it cleanly.
    `mission`: the mission file, loaded by the caller already (`load_inputs`)."""

    async def main() -> dict:
        task = asyncio.current_task()
        loop = asyncio.get_running_loop()
        assert task is not None
        # SIGINT too, and explicitly: a launcher started in the background of a script
        # inherits an ignored SIGINT, while its agents install their own handler and stop
        # on Ctrl-C; the launcher would then report them as failed instead of stopping.
        with contextlib.suppress(NotImplementedError):
            for sig in (signal.SIGINT, signal.SIGTERM):
                loop.add_signal_handler(sig, task.cancel)
        return await swarm_up(opts, mission=mission)

    try:
        return asyncio.run(main())
    except asyncio.CancelledError:
        raise KeyboardInterrupt from None


def status(broker: str, swarm: str, drop_after_missed: int = 2, key: SwarmKey | None = None,
           credentials: tuple[str, str] | None = None) -> None:
    """`plmarl swarm status`: attach the live view to a running swarm over MQTT (the
    signalling of a signed swarm is shown only with its key)."""
    from rich.console import Console
    from rich.live import Live

    async def main() -> None:
        parse_broker_url(broker)  # UserError on a malformed URL
        monitor = SwarmMonitor(swarm, 15, drop_after_missed, wire=Wire(key))
        t = monitor.topics
        bus = MqttBus(broker, f"plmarl-status-{swarm}-{id(monitor) % 10000}", [t.metrics, t.tx("+"), t.rx("+")], monitor.on_bus,
                      name="status-bus", credentials=credentials)
        console = Console()
        async with asyncio.TaskGroup() as tg:
            tg.create_task(bus.run())
            with Live(render(monitor.view()), console=console, refresh_per_second=4) as live:
                while True:
                    live.update(render(monitor.view()))
                    await asyncio.sleep(0.25)

    asyncio.run(main())


if __name__ == "__main__":  # pragma: no cover - debugging aid
    print(json.dumps(run_up(UpOptions(Path(sys.argv[1]), speedup=10, headless=True))))
