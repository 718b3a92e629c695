"""The hosts file of a swarm spread over machines (`plmarl swarm up MISSION --hosts HOSTS.yaml`).

    launcher:
      address: 10.0.0.1          # where the broker and the vehicles' MAVLink UDP ports listen
      broker_port: 1883          # optional (default: a free port), for a firewall rule
      vehicle_base_port: 14540   # optional: vehicle i on vehicle_base_port + i (default: free ports)
    connect_timeout_s: 20        # optional: how long a host may take to answer at start
    silence_s: 3                 # optional: a host none of whose agents is heard this long is lost
    hosts:
      - name: companion-a
        run: [ssh, -o, BatchMode=yes, -o, ConnectTimeout=5, pi@10.0.0.2]   # a command prefix
        address: 10.0.0.2        # the address the launcher's host sees it on
        uavs: [0, 1]
        python: /home/pi/plmarl/.venv/bin/python   # optional (default python3)

The world (with its emulated autopilots) and the broker stay on the launcher's host; the
UAVs a host lists fly under agents started there through its `run` prefix
(`sitl/remote.py`, `deploy/companion.py`); the others run on the launcher's host as
without a hosts file. Loaded strictly, like a mission: an unknown key or a wrong type
names its path (`hosts[1].uavs[0]: expected an integer`).
"""

from __future__ import annotations

import ipaddress
import re
import socket
from dataclasses import dataclass, field
from pathlib import Path

from plmarl_sitl.config import ConfigError, _require, load_yaml
from plmarl_sitl.deploy.mqtt.url import parse_broker_url
from plmarl_sitl.errors import UserError

NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]*")
# The interpreter's path is one word of a remote shell's command line (ssh joins argv
# with spaces): no quoting is needed, and none can go wrong, when it has no metacharacters.
PYTHON = re.compile(r"[A-Za-z0-9._/+~-]+")


@dataclass(frozen=True)
class LauncherHost:
    address: str
    broker_port: int | None = field(default=None, metadata={"min": 1, "max": 65535})
    vehicle_base_port: int | None = field(default=None, metadata={"min": 1, "max": 65535})

    def __post_init__(self) -> None:
        _require(bool(self.address.strip()), "address", "must not be empty")


@dataclass(frozen=True)
class Host:
    name: str
    run: tuple[str, ...]
    address: str
    uavs: tuple[int, ...]
    python: str = "python3"

    def __post_init__(self) -> None:
        _require(NAME.fullmatch(self.name) is not None, "name", "letters, digits, '.', '_' and '-' only")
        _require(len(self.run) > 0, "run", "a command prefix, e.g. [ssh, user@host] or [ip, netns, exec, NS]")
        _require(all(a != "" for a in self.run), "run", "an empty argument")
        _require(bool(self.address.strip()), "address", "must not be empty")
        _require(len(self.uavs) > 0, "uavs", "list at least one UAV id (or leave the host out)")
        for k, u in enumerate(self.uavs):
            _require(u >= 0, f"uavs[{k}]", "must be >= 0")
        _require(len(set(self.uavs)) == len(self.uavs), "uavs", "a UAV id is listed twice")
        _require(PYTHON.fullmatch(self.python) is not None, "python", "a path without spaces or shell metacharacters")


@dataclass(frozen=True)
class HostsFile:
    launcher: LauncherHost
    hosts: tuple[Host, ...]
    connect_timeout_s: float = field(default=20.0, metadata={"min": 0.5})
    silence_s: float = field(default=3.0, metadata={"min": 1.5})  # > the agents' 1 Hz heartbeat

    def __post_init__(self) -> None:
        names: set[str] = set()
        where: dict[int, str] = {}
        for k, h in enumerate(self.hosts):
            _require(h.name not in names, f"hosts[{k}].name", f"{h.name!r} is used twice")
            names.add(h.name)
            for u in h.uavs:
                _require(u not in where, f"hosts[{k}].uavs", f"UAV {u} is placed on {where.get(u)!r} already")
                where[u] = h.name

    def host_of(self, uav: int) -> Host | None:
        """The host UAV `uav`'s agent runs on; None: the launcher's host."""
        return next((h for h in self.hosts if uav in h.uavs), None)


def load_hosts(path: Path, n_uavs: int, autopilot: str = "emulator", broker: str = "embedded") -> HostsFile:
    """The hosts file at `path`, checked against a mission of `n_uavs` UAVs, the run's
    autopilots and broker, and this machine (the launcher's address must be one of its
    own). Raises ConfigError or UserError (one line, exit 2), naming the file and the key."""
    if autopilot != "emulator":
        raise UserError("--hosts needs the emulated autopilots (the world's vehicles are what remote agents fly)")
    if broker not in ("embedded", "mosquitto") and parse_broker_url(broker)[0] in ("127.0.0.1", "localhost", "::1"):
        raise UserError(f"--hosts with the broker {broker}: a loopback address the other hosts cannot reach")
    hosts = load_yaml(HostsFile, path)
    for k, h in enumerate(hosts.hosts):
        for j, u in enumerate(h.uavs):
            if u >= n_uavs:
                raise ConfigError(f"hosts[{k}].uavs[{j}]", f"UAV {u}: the mission has UAVs 0-{n_uavs - 1}", str(path))
    _check_bindable(hosts.launcher.address, str(path))
    return hosts


def _check_bindable(address: str, source: str) -> None:
    """The launcher's address must be this machine's: the broker and the vehicles bind it."""
    try:
        family = socket.AF_INET6 if ipaddress.ip_address(address).version == 6 else socket.AF_INET
    except ValueError:
        family = socket.AF_INET  # a host name: resolved by bind
    try:
        with socket.socket(family, socket.SOCK_DGRAM) as s:
            s.bind((address, 0))
    except OSError as exc:
        raise ConfigError("launcher.address", f"{address} is not an address of this machine "
                          f"({exc.strerror or exc})", source) from None
