"""A `swarm up` run's inputs: everything it reads for what it is asked (`sitl.options.UpOptions`),
validated and loaded once, before anything is created (`load_inputs`).

A missing, exposed or malformed key, a malformed broker URL, an unusable policy or hosts
file is one line before the run directory, the broker or any process exists; and what is
loaded here is what the run uses (the mission with --seed applied, the keys given, an
external broker's logins), so no input is read twice.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

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
from plmarl_sitl.sitl.options import OWN_BROKERS, UpOptions
from plmarl_sitl.sitl.px4 import find_build


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


def load_inputs(opts: UpOptions, mission: Mission | None = None) -> RunInputs:
    """Raises UserError (or ConfigError) naming the input that is wrong. `mission`: the
    mission file as `load_mission` returned it, when the caller has loaded it already
    (`plmarl swarm up` does, before its fork server: a wrong key is said at once)."""
    mission = load_mission(opts.mission_path) if mission is None else mission
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
    if opts.autopilot != "emulator" and schedule.has("gnss_noise"):
        raise UserError(f"gnss_noise events need emulated autopilots (a real {opts.autopilot} navigates on its own GNSS)")
    if opts.broker not in OWN_BROKERS:
        parse_broker_url(opts.broker)  # a malformed URL fails before anything is created
    swarm_key = load_key(opts.swarm_key) if opts.swarm_key is not None else None
    mavlink_keys = None
    if opts.mavlink_keys is not None:
        mavlink_keys = load_key_files(opts.mavlink_keys, n, "--mavlink-keys")
    login_files: dict[str, Path] = {}
    if opts.broker_credentials is not None:
        names = ["world", "monitor", *(f"agent{i}" for i in range(n))]
        login_files = {name: opts.broker_credentials / f"{name}.cred" for name in names}
    logins = {name: load_credentials(path) for name, path in login_files.items()}  # missing, exposed or malformed: one error
    if not (opts.policy / "card.yaml").exists():
        raise UserError(f"--policy {opts.policy}: no card.yaml there (train one with `plmarl train` or use policies/pl-marl)")
    # A corrupt or mismatched policy is one line here, not an agent's exit after start-up.
    size_warning = swarm_size_warning(load_policy(opts.policy, mission).card, n)
    hosts = load_hosts(opts.hosts, n, opts.autopilot, opts.broker) if opts.hosts is not None else None
    return RunInputs(mission, schedule, copter_parm, size_warning, hosts, swarm_key, mavlink_keys, login_files, logins)
