"""The launcher's end of a swarm spread over hosts: agents started on other machines.

For every host of the hosts file (`sitl/hosts.py`) the launcher runs one process, the host's
command prefix followed by `PYTHON -m plmarl_sitl.deploy.companion` (over SSH on a real
cluster: one connection per host, whatever its number of UAVs), and drives it with JSON
lines on its stdin and stdout (the protocol is in `deploy/companion.py`). Each agent placed
there gets its files through that stdin (the resolved mission, the policy, the swarm key,
its broker login and its MAVLink key), runs as `plmarl agent` with the same arguments as a
local one, and talks to the world and the broker over the network like any agent: MAVLink
UDP to its vehicle's port and MQTT to the broker, both at the launcher's address, signed,
with its own login and ACL. Its output comes back into agents/agentI.log, its trace and
stats when it exits. A `RemoteAgent` is the process-like handle `AgentFleet` keeps for it.

A host is lost (`RemoteHosts.lost`) when none of its live agents has been heard on MAVLink
(the world's per-vehicle datagram counters: every flying agent sends a setpoint at >= 5 Hz
and a heartbeat at 1 Hz of wall time) for the hosts file's `silence_s`; the launcher then
records its UAVs as node failures.
"""

from __future__ import annotations

import asyncio
import base64
import contextlib
import json
import logging
import os
import shlex
import signal
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from plmarl_sitl.config import read_yaml
from plmarl_sitl.deploy.companion import BUNDLE, LINE_LIMIT
from plmarl_sitl.deploy.mqtt.url import parse_broker_url
from plmarl_sitl.errors import PlmarlError
from plmarl_sitl.learning.nn.io import FILES as POLICY_FILES
from plmarl_sitl.sitl.hosts import Host, HostsFile

log = logging.getLogger("plmarl.hosts")

# `plmarl agent` options that name a file it reads, and where the file goes in the bundle.
INPUT_FILES = {"--mission": "mission", "--swarm-key": "keys", "--broker-credentials": "keys", "--mavlink-key": "keys"}
OUTPUT_FILES = {"--trace": "trace", "--stats-json": "stats"}
PING_S = 1.0  # the launcher tells each companion it is there ...
FENCE_S = 10.0  # ... which stops its agents after this long without a word (a cut link)
ABANDON_AFTER_KILL_S = 3.0  # a host that does not confirm a SIGKILL within this is cut loose
CLOSE_GRACE_S = 8.0  # the companion stops its agents (5 s grace each) and says bye


class HostFailed(PlmarlError):
    """A host could not be reached or its companion failed; the message is one line."""


class RemoteAgent:
    """The part of `asyncio.subprocess.Process` the fleet uses, for an agent on another host."""

    def __init__(self, host: RemoteHost, uav: int) -> None:
        self.host, self.uav = host, uav
        self.pid: int | None = None  # on the other host
        self.returncode: int | None = None
        self.exited = asyncio.Event()

    def send_signal(self, sig: int) -> None:
        if self.returncode is None:
            self.host.send(op="signal", uav=self.uav, sig=int(sig))
            if sig == signal.SIGKILL:  # bounded: a host that cannot confirm it is cut loose
                asyncio.get_running_loop().call_later(ABANDON_AFTER_KILL_S, self.host.abandon_if_silent, self.uav)

    def finish(self, code: int) -> None:
        if self.returncode is None:
            self.returncode = code
            self.exited.set()

    async def wait(self) -> int:
        await self.exited.wait()
        assert self.returncode is not None
        return self.returncode


@dataclass
class RemoteHost:
    """One host's companion process and the agents it runs."""

    host: Host
    log_dir: Path
    agents: dict[int, RemoteAgent] = field(default_factory=dict)
    proc: asyncio.subprocess.Process | None = None
    _outputs: dict[tuple[int, str], Path] = field(default_factory=dict)
    _logs: dict[int, Path] = field(default_factory=dict)
    _shipped: set[str] = field(default_factory=set)
    _hello: asyncio.Future | None = None
    _error: str | None = None
    _reader: asyncio.Task | None = None
    _pinger: asyncio.Task | None = None
    closed: bool = False  # its companion has exited: nothing there runs any more

    @property
    def command(self) -> list[str]:
        return [*self.host.run, self.host.python, "-m", "plmarl_sitl.deploy.companion", "--name", self.host.name]

    def said(self) -> str:
        """The last line the host's command wrote on stderr (ssh's, say), for an error message."""
        path = self.log_dir / f"{self.host.name}.stderr"
        lines = [ln for ln in path.read_text(errors="replace").splitlines() if ln.strip()] if path.exists() else []
        return lines[-1].strip()[-200:] if lines else ""

    async def connect(self, reach: str, timeout_s: float) -> str:
        """Start the companion and wait until it has reached the broker at `reach` (HOST:PORT);
        returns the address it reaches it from. Raises HostFailed in one line."""
        self.log_dir.mkdir(parents=True, exist_ok=True)
        loop = asyncio.get_running_loop()
        self._hello = loop.create_future()
        cmd = [*self.command, "--reach", reach, "--fence", f"{FENCE_S:g}"]
        log.info("host %s: %s", self.host.name, shlex.join(cmd))
        with open(self.log_dir / f"{self.host.name}.stderr", "wb") as err:
            try:
                # A session of its own: a terminal's Ctrl-C goes to the launcher, which stops the
                # agents in order, not to ssh, which would drop the connection under them.
                self.proc = await asyncio.create_subprocess_exec(
                    *cmd, stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE, stderr=err,
                    start_new_session=True, limit=LINE_LIMIT)
            except OSError as exc:
                raise HostFailed(f"host {self.host.name}: cannot run {self.host.run[0]!r}: {exc.strerror or exc}") from exc
        self._reader = asyncio.create_task(self._read(), name=f"host-{self.host.name}")
        try:
            async with asyncio.timeout(timeout_s):
                source = await self._hello
        except TimeoutError:
            raise HostFailed(f"host {self.host.name} did not answer within {timeout_s:g} s "
                             f"({shlex.join(self.host.run)}){self._tail()}") from None
        self._pinger = asyncio.create_task(self._ping(), name=f"host-{self.host.name}-ping")
        if source != self.host.address:
            log.warning("host %s reaches the broker from %s, the hosts file says %s", self.host.name, source, self.host.address)
        return str(source)

    async def _ping(self) -> None:
        while self.proc is not None and self.proc.returncode is None:
            self.send(op="ping")
            await asyncio.sleep(PING_S)

    def _tail(self) -> str:
        said = self.said()
        return f": {said}" if said else ""

    async def _read(self) -> None:
        assert self.proc is not None and self.proc.stdout is not None and self._hello is not None
        try:
            while line := await self.proc.stdout.readline():
                try:
                    self._on(json.loads(line))
                except (ValueError, KeyError, TypeError, OSError) as exc:
                    log.warning("host %s: bad line from its companion (%s): %r", self.host.name, exc, line[:200])
        except (ValueError, OSError) as exc:  # a line over the limit, a broken pipe
            log.warning("host %s: its output broke: %s", self.host.name, exc)
        code = await self.proc.wait()
        self.closed = True
        if not self._hello.done():
            why = self._error or f"{shlex.join(self.host.run)} exited with code {code} before it answered{self._tail()}"
            self._hello.set_exception(HostFailed(f"host {self.host.name}: {why}"))
        for a in self.agents.values():
            a.finish(255 if a.returncode is None else a.returncode)  # the connection is gone: so are they

    def _on(self, msg: dict) -> None:
        op = msg["op"]
        if op == "hello":
            assert self._hello is not None
            if not self._hello.done():
                self._hello.set_result(msg.get("source"))
        elif op == "error":
            self._error = str(msg["text"])
            log.warning("host %s: %s", self.host.name, self._error)
        elif op == "started":
            self.agents[int(msg["uav"])].pid = int(msg["pid"])
        elif op == "log":
            with open(self._logs[int(msg["uav"])], "a") as f:
                f.write(str(msg["text"]) + "\n")
        elif op == "file":
            path = self._outputs.get((int(msg["uav"]), str(msg["key"])))
            if path is not None:
                path.write_bytes(base64.b64decode(msg["data"]))
        elif op == "exit":
            self.agents[int(msg["uav"])].finish(int(msg["code"]))

    def send(self, **msg: object) -> None:
        if self.proc is None or self.proc.stdin is None or self.proc.stdin.is_closing():
            return
        self.proc.stdin.write(json.dumps(msg).encode() + b"\n")

    def _ship(self, rel: str, data: bytes) -> None:
        if rel not in self._shipped:
            self.send(op="file", path=rel, data=base64.b64encode(data).decode())
            self._shipped.add(rel)

    def _ship_mission(self, path: Path) -> str:
        """The resolved mission; a vehicle model given as a file travels with it."""
        data = read_yaml(path)  # the run's mission.yaml, written by the launcher
        vehicle = Path(str(data.get("vehicle", "")))
        if vehicle.suffix:  # a file, not a name in vehicle_models/ (which the host has installed)
            self._ship(f"mission/{vehicle.name}", vehicle.read_bytes())
            data["vehicle"] = f"{BUNDLE}/mission/{vehicle.name}"
        self._ship("mission/mission.yaml", yaml.safe_dump(data, sort_keys=False).encode())
        return f"{BUNDLE}/mission/mission.yaml"

    async def spawn(self, uav: int, argv: Sequence[str], log_path: Path, nice: int) -> RemoteAgent:
        """Start `plmarl agent ARGV` there: every file ARGV names is shipped and renamed into
        the host's bundle directory; output files come back to their local paths at exit."""
        args, outputs = list(argv), {}
        for k, a in enumerate(args[:-1]):
            value = Path(args[k + 1])
            if a == "--mission":
                args[k + 1] = self._ship_mission(value)
            elif a in INPUT_FILES:
                rel = f"{INPUT_FILES[a]}/{value.name}"
                self._ship(rel, value.read_bytes())
                args[k + 1] = f"{BUNDLE}/{rel}"
            elif a == "--policy":
                for name in POLICY_FILES:
                    self._ship(f"policy/{name}", (value / name).read_bytes())
                args[k + 1] = f"{BUNDLE}/policy"
            elif a in OUTPUT_FILES:
                rel = f"out/{value.name}"
                outputs[OUTPUT_FILES[a]] = rel
                self._outputs[(uav, OUTPUT_FILES[a])] = value
                args[k + 1] = f"{BUNDLE}/{rel}"
        log_path.write_text(f"# agent {uav} on host {self.host.name} ({self.host.address})\n")
        self._logs[uav] = log_path
        agent = self.agents[uav] = RemoteAgent(self, uav)
        if self.closed:
            agent.finish(255)  # its host's connection is gone already
            return agent
        self.send(op="start", uav=uav, argv=args, outputs=outputs, nice=nice)
        assert self.proc is not None and self.proc.stdin is not None
        with contextlib.suppress(ConnectionError):
            await self.proc.stdin.drain()
        return agent

    def abandon_if_silent(self, uav: int) -> None:
        """A SIGKILL the host did not confirm: end the connection (its companion then stops
        whatever it still runs, once the end reaches it)."""
        if self.agents[uav].returncode is None:
            log.warning("host %s did not confirm agent %d's SIGKILL: closing its connection", self.host.name, uav)
            self.kill()
            if self.closed:
                self.agents[uav].finish(255)

    def kill(self) -> None:
        if self.proc is not None and self.proc.returncode is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.proc.pid, signal.SIGKILL)

    async def close(self) -> None:
        """Stop the agents still running there and the companion; bounded."""
        if self._pinger is not None:
            self._pinger.cancel()
        if self.proc is None:
            return
        if self._hello is None or not self._hello.done() or self._hello.cancelled() or self._hello.exception():
            self.kill()  # it never answered: nothing of ours runs there yet
        self.send(op="stop")
        if self.proc.stdin is not None:
            self.proc.stdin.close()
        try:
            async with asyncio.timeout(CLOSE_GRACE_S):
                await self.proc.wait()
        except TimeoutError:
            log.warning("host %s: its companion did not exit within %g s: killed", self.host.name, CLOSE_GRACE_S)
        self.kill()  # the whole session: a prefix's own children too (a shell's, say)
        await self.proc.wait()
        if self._reader is not None:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await self._reader


class RemoteHosts:
    """Every host of a hosts file: start-up, placement, loss, shutdown."""

    def __init__(self, hosts: HostsFile, log_dir: Path) -> None:
        self.file = hosts
        self.hosts = [RemoteHost(h, log_dir) for h in hosts.hosts]
        self.placement: dict[int, RemoteHost] = {u: r for r in self.hosts for u in r.host.uavs}
        self.gone: set[str] = set()  # hosts declared lost
        self._heard: dict[str, tuple[tuple[int, ...], int, float]] = {}  # host -> (members, datagrams, wall s)

    async def connect(self, broker_url: str) -> list[str]:
        """Every host's companion, started at once, each reaching the broker from its host;
        raises HostFailed (one line) for the first that fails. Returns a line per host."""
        host, port = parse_broker_url(broker_url)
        reach = f"{host}:{port}"
        results = await asyncio.gather(*(r.connect(reach, self.file.connect_timeout_s) for r in self.hosts),
                                       return_exceptions=True)
        for res in results:
            if isinstance(res, BaseException):
                raise res
        return [f"host {r.host.name} ({source}) flies UAVs {', '.join(map(str, r.host.uavs))}: broker {reach} reached "
                "from there" for r, source in zip(self.hosts, results, strict=True)]

    def lost(self, datagrams: Sequence[int], out_of_mission: set[int], now: float) -> list[Host]:
        """Hosts lost as of wall time `now`: none of their agents still in the mission (not in
        `out_of_mission`) sent a datagram (`datagrams[i]`: vehicle i's count) for silence_s."""
        lost = []
        for r in self.hosts:
            h = r.host
            if h.name in self.gone:
                continue
            members = tuple(u for u in h.uavs if u not in out_of_mission)
            if not members:
                continue
            count = sum(int(datagrams[u]) for u in members)
            seen = self._heard.get(h.name)
            if seen is None or seen[0] != members or seen[1] != count:
                self._heard[h.name] = (members, count, now)
            elif now - seen[2] >= self.file.silence_s:
                self.gone.add(h.name)
                lost.append(h)
        return lost

    async def close(self) -> None:
        await asyncio.gather(*(r.close() for r in self.hosts), return_exceptions=True)
