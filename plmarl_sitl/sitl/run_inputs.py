"""A `swarm up` run's inputs: what it is asked (`UpOptions`), and everything it reads,
validated and loaded once, before anything is created (`load_inputs`).

A missing, exposed or malformed key, a malformed broker URL, an unusable policy or hosts
file is one line before the run directory, the broker or any process exists; and what is
loaded here is what the run uses (the mission with --seed applied, the keys given, an
external broker's logins), so no input is read twice.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

from plmarl_sitl.config import PROJECT_POLICIES
from plmarl_sitl.deploy.mavlink.keys import load_key_files
from plmarl_sitl.deploy.mqtt.auth import SwarmKey, load_key
from plmarl_sitl.deploy.mqtt.credentials import load_credentials
from plmarl_sitl.deploy.mqtt.url import parse_broker_url
from plmarl_sitl.errors import UserError
from plmarl_sitl.learning.nn.card import swarm_size_warning
from plmarl_sitl.learning.nn.io import load_policy
from plmarl_sitl.mission import Mission, load_mission
from plmarl_sitl.model.events import EventSchedule
from plmarl_sitl.sitl.arducopter import check_binary, find_copter_parm
from plmarl_sitl.sitl.hosts import HostsFile, load_hosts
from plmarl_sitl.sitl.lockstep import DEFAULT_STRAGGLER_S
from plmarl_sitl.sitl.px4 import find_build

OWN_BROKERS = ("embedded", "mosquitto")  # brokers swarm up starts itself (fresh logins)
DEFAULT_POLICY = PROJECT_POLICIES / "pl-marl"


@dataclass(frozen=True)
class UpOptions:
    mission_path: Path
    speedup: float = 1.0
    duration_s: int | None = None  # mission seconds; None: the mission's episode length
    broker: str = "embedded"
    headless: bool = False
    out: Path | None = None
    seed: int | None = None
    policy: Path = DEFAULT_POLICY
    personality: str = "px4"
    boot: str = "instant"  # emulated autopilots' start-up: instant or real (measured timeline)
    swarm: str = "sitl"
    start_timeout_s: float | None = None  # wall s for every vehicle to get airborne (None: 120; ArduCopter: more)
    # The autopilots: "emulator" (in the world's process, `personality`, `boot`) or
    # "arducopter" (a real ArduCopter SITL process per UAV, the binary `arducopter`) or
    # "px4" (a real PX4 SITL process with SIH per UAV, `px4` its build output).
    autopilot: str = "emulator"
    arducopter: Path | None = None
    px4: Path | None = None
    copter_parm: Path | None = None  # ArduPilot's copter.parm (None: found above the binary)
    instance_base: int | None = None  # first ArduPilot SITL instance -I, PX4 -i (None: the first free ones)
    verbose: bool = False  # agents log DEBUG too
    # Message authentication (docs/SECURITY.md): a fresh swarm key per run in the run
    # directory (swarm.key, 0600), or the key file given; auth=False flies unsigned.
    auth: bool = True
    swarm_key: Path | None = None
    # An external broker's logins: DIR/world.cred, DIR/monitor.cred, DIR/agentI.cred (None: anonymous).
    broker_credentials: Path | None = None
    # MAVLink 2 signing between each autopilot and its agent (and the world's links): a fresh
    # key per vehicle in RUN_DIR/mavlink/vehicleI.key (0600), or DIR/vehicleI.key given.
    mavlink_sign: bool = True
    mavlink_keys: Path | None = None
    # Lockstep (emulated autopilots only, `sitl.lockstep`): deterministic, as fast as the agents
    # compute; an agent owing an answer for straggler_s wall seconds is declared failed.
    lockstep: bool = False
    straggler_s: float = DEFAULT_STRAGGLER_S
    hosts: Path | None = None  # a hosts file: some agents on other machines (`sitl.hosts`)

    def start_timeout(self) -> float:
        """A real ArduCopter needs ~40 s of vehicle time to boot and a climb at 2.5 m/s; a real PX4
        ~37 s to OFFBOARD at 60 m (it climbs at ~2 m/s)."""
        if self.start_timeout_s is not None:
            return self.start_timeout_s
        return 120.0 if self.autopilot == "emulator" else max(120.0, 60.0 + 150.0 / self.speedup)


@dataclass(frozen=True)
class RunInputs:
    mission: Mission  # --seed applied
    schedule: EventSchedule  # the mission's events, for the world, the launcher and the gate
    copter_parm: Path | None  # a real ArduCopter's copter.parm
    size_warning: str | None  # the policy was trained for another swarm size
    hosts: HostsFile | None
    swarm_key: SwarmKey | None  # the key file given, loaded (None: a fresh one, or --no-auth)
    mavlink_keys: list[bytes] | None  # the MAVLink keys given, loaded (None: fresh ones, or unsigned)
    # An external broker's logins, by process (world, monitor, agentI): the files, and what they say.
    login_files: dict[str, Path]
    logins: dict[str, tuple[str, str]]


def fault_autopilot(opts: UpOptions) -> str:
    """Whose measured reaction to a GPS loss the run's schedule applies: the vehicles' autopilot."""
    if opts.autopilot == "emulator":
        return opts.personality
    return {"arducopter": "ardupilot", "px4": "px4"}[opts.autopilot]


def load_inputs(opts: UpOptions) -> RunInputs:
    """Raises UserError (or ConfigError) naming the input that is wrong."""
    mission = load_mission(opts.mission_path)
    if opts.seed is not None:
        mission = replace(mission, seed=opts.seed)
    # Autopilot faults take a UAV out as its autopilot was measured to (model.events).
    schedule = EventSchedule.of(mission, fault_autopilot(opts))
    n = mission.n_uavs
    copter_parm = None
    if opts.autopilot == "arducopter":
        assert opts.arducopter is not None
        copter_parm = find_copter_parm(check_binary(opts.arducopter), opts.copter_parm)
    elif opts.autopilot == "px4":
        assert opts.px4 is not None
        find_build(opts.px4)  # not a PX4 SITL build: one line before anything starts
        if opts.mavlink_keys is not None:
            raise UserError("--mavlink-keys with --autopilot px4: PX4 has no MAVLink signing to give them to")
    if opts.autopilot != "emulator" and schedule.has("gnss_noise"):
        raise UserError(f"gnss_noise events need emulated autopilots (a real {opts.autopilot} navigates on its own GNSS)")
    if opts.broker not in OWN_BROKERS:
        parse_broker_url(opts.broker)  # a malformed URL fails before anything is created
    swarm_key = load_key(opts.swarm_key) if opts.swarm_key is not None else None
    mavlink_keys = None
    if opts.mavlink_keys is not None:
        if not opts.mavlink_sign:
            raise UserError("--mavlink-keys with --no-mavlink-sign: choose one")
        mavlink_keys = load_key_files(opts.mavlink_keys, n, "--mavlink-keys")
    login_files: dict[str, Path] = {}
    if opts.broker_credentials is not None:
        if opts.broker in OWN_BROKERS:
            raise UserError("--broker-credentials is for an external broker (the brokers swarm up starts get fresh logins)")
        names = ["world", "monitor", *(f"agent{i}" for i in range(n))]
        login_files = {name: opts.broker_credentials / f"{name}.cred" for name in names}
    logins = {name: load_credentials(path) for name, path in login_files.items()}  # missing, exposed or malformed: one error
    if not (opts.policy / "card.yaml").exists():
        raise UserError(f"--policy {opts.policy}: no card.yaml there (train one with `plmarl train` or use policies/pl-marl)")
    # A corrupt or mismatched policy is one line here, not an agent's exit after start-up.
    size_warning = swarm_size_warning(load_policy(opts.policy, mission).card, n)
    hosts = load_hosts(opts.hosts, n, opts.autopilot, opts.broker) if opts.hosts is not None else None
    return RunInputs(mission, schedule, copter_parm, size_warning, hosts, swarm_key, mavlink_keys, login_files, logins)
