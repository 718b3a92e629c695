"""Agent processes for a SITL run: spawn `plmarl agent` children, stop them, never orphan them.

Used by the integration tests, `plmarl bench agent` and the sim-to-SITL gap run; the
launcher builds on it. Every child gets OPENBLAS/OMP threads = 1 and its own log file.
A fleet either execs each agent (`python -m plmarl_sitl.cli agent ...`, exactly what a
user runs) or, with `forked=True`, forks it from a fork server that has imported torch
once (`sitl.forked`), which is how a launcher starts 20 agents on 2 cores quickly. The
UAVs in `remote` run on other hosts (`sitl.remote`), with the same arguments.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import json
import os
import signal
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import psutil

from plmarl_sitl.proc import agent_child_setup
from plmarl_sitl.sitl.forked import ForkedProcess, fork_agent, warm_up
from plmarl_sitl.sitl.remote import RemoteAgent

if TYPE_CHECKING:
    from plmarl_sitl.sitl.remote import RemoteHost


@dataclass
class AgentProc:
    uav_id: int
    proc: asyncio.subprocess.Process | ForkedProcess | RemoteAgent
    log_path: Path
    trace_path: Path | None
    stats_path: Path | None

    def trace(self) -> list[dict]:
        if self.trace_path is None or not self.trace_path.exists():
            return []
        return [json.loads(line) for line in self.trace_path.read_text().splitlines() if line.strip()]

    def stats(self) -> dict | None:
        if self.stats_path is None or not self.stats_path.exists():
            return None
        return json.loads(self.stats_path.read_text())

    def log(self) -> str:
        return self.log_path.read_text(errors="replace") if self.log_path.exists() else ""


SITL_AGENT_NICE = 5


def _signal(p: asyncio.subprocess.Process | ForkedProcess | RemoteAgent, sig: int) -> None:
    """Signal a running agent with os.kill. Not `p.send_signal`/`p.kill`: for an exec'd agent
    they are `Popen.send_signal`, which polls first, and that waitpid can reap an agent that
    has just exited before asyncio's child watcher does; the watcher then reports exit 255
    ("Unknown child process") instead of the agent's own code. An exited agent keeps its pid
    until it is reaped; the one window left is the instant between the watcher's reap and its
    callback setting returncode (pids are handed out in sequence: a reuse within it is remote).
    An agent on another host gets the signal from its companion there."""
    if isinstance(p, RemoteAgent):
        p.send_signal(sig)
    elif p.returncode is None:
        with contextlib.suppress(ProcessLookupError):
            os.kill(p.pid, sig)


# CPU s an agent must have used since the world last asked to count as still computing: an
# agent idling in its event loop (heartbeat, bus keep-alive, link checks: ~3 wake-ups a
# second) uses a few ms in a 10 s straggler bound; one of 100 deciding on a starved machine
# (a quarter of a core between them) about 25 ms.
WORKING_CPU_S = 0.01


@dataclass
class AgentFleet:
    """Children started by `spawn`; `stop()` (SIGTERM, then SIGKILL) in any case.

    `nice` is added to every agent's niceness. A SITL swarm runs its agents at
    SITL_AGENT_NICE: the world process and the broker stand in for physics, autopilots and
    radios, which never wait for a companion computer's CPU. At equal priority, 20 agents
    waking together on 2 cores held the broker's and the world's signalling for tens of
    milliseconds (most of a second of vehicle time at 15x)."""

    workdir: Path
    forked: bool = False
    nice: int = 0
    procs: dict[int, AgentProc] = field(default_factory=dict)
    remote: dict[int, RemoteHost] = field(default_factory=dict)  # UAVs whose agent runs on another host
    _cpu_seen: dict[int, float] = field(default_factory=dict)  # CPU s of each agent at the last `working`

    def working(self, uav_ids: list[int]) -> list[int]:
        """The agents among `uav_ids` that used WORKING_CPU_S of CPU or more since the last
        call that asked about them (first asked: counted as working). A lockstep world asks before it declares an
        agent that owes an answer failed: on a machine so loaded that 100 agents deciding at
        once take longer than the straggler bound between them, every one of them is still
        computing, where a stopped or hung one is not (issue 25). Agents on other hosts and
        exited ones are not working."""
        busy = []
        for i in uav_ids:
            ap = self.procs.get(i)
            if ap is None or i in self.remote or ap.proc.returncode is not None:
                continue
            try:
                t = psutil.Process(ap.proc.pid).cpu_times()
            except psutil.Error:
                continue
            cpu = t.user + t.system
            if cpu >= self._cpu_seen.get(i, -1.0) + WORKING_CPU_S:
                busy.append(i)
            self._cpu_seen[i] = cpu
        return busy

    def warm_up(self, policy: str | Path | None = None, mission: str | Path | None = None) -> None:
        """Forked fleets: get the fork server importing (and loading `policy` for `mission`)
        before the first `spawn`."""
        if self.forked:
            warm_up(policy, mission)

    async def spawn(
        self,
        uav_id: int,
        connect_url: str,
        broker_url: str,
        *,
        mission: str | Path,
        policy: str | Path,
        n_uavs: int | None = None,
        swarm: str = "sitl",
        tup_s: int | None = None,
        extra: list[str] | None = None,
        trace: bool = True,
        stats: bool = True,
        verbose: bool = False,
        swarm_key: Path | None = None,
        credentials: Path | None = None,
        mavlink_key: Path | None = None,
    ) -> AgentProc:
        """Start agent `uav_id`; it signs its messages with the key file `swarm_key`, or
        flies unsigned (`--no-auth`) without one, and logs in to the broker with the
        credentials file `credentials` (None: anonymous)."""
        self.workdir.mkdir(parents=True, exist_ok=True)
        trace_path = self.workdir / f"agent{uav_id}.trace.jsonl" if trace else None
        stats_path = self.workdir / f"agent{uav_id}.stats.json" if stats else None
        log_path = self.workdir / f"agent{uav_id}.log"
        cmd = ["--id", str(uav_id), "--connect", connect_url,
               "--broker", broker_url, "--mission", str(mission), "--policy", str(policy), "--swarm", swarm]
        cmd += ["--swarm-key", str(swarm_key)] if swarm_key is not None else ["--no-auth"]
        if credentials is not None:
            cmd += ["--broker-credentials", str(credentials)]
        if mavlink_key is not None:  # sign the link to the autopilot
            cmd += ["--mavlink-key", str(mavlink_key)]
        if verbose:  # DEBUG for the plmarl loggers: only when asked for
            cmd.append("-v")
        if n_uavs is not None:
            cmd += ["--n-uavs", str(n_uavs)]
        if tup_s is not None:
            cmd += ["--tup", str(tup_s)]
        if trace_path is not None:
            cmd += ["--trace", str(trace_path)]
        if stats_path is not None:
            cmd += ["--stats-json", str(stats_path)]
        cmd += extra or []
        threads = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}
        proc: asyncio.subprocess.Process | ForkedProcess | RemoteAgent
        if uav_id in self.remote:
            proc = await self.remote[uav_id].spawn(uav_id, cmd, log_path, nice=self.nice)
        elif self.forked:
            proc = await fork_agent(cmd, str(log_path), threads, name=f"plmarl-agent{uav_id}", nice=self.nice)
        else:
            with open(log_path, "wb") as log:
                proc = await asyncio.create_subprocess_exec(
                    sys.executable, "-m", "plmarl_sitl.cli", "agent", *cmd, stdout=log, stderr=asyncio.subprocess.STDOUT,
                    env=dict(os.environ, **threads), preexec_fn=functools.partial(agent_child_setup, self.nice),
                )
        ap = AgentProc(uav_id, proc, log_path, trace_path, stats_path)
        self.procs[uav_id] = ap
        self.procs = dict(sorted(self.procs.items()))  # by id, whatever order concurrent spawns finish in
        return ap

    def kill(self, uav_id: int) -> None:
        """Abrupt process death (SIGKILL): no hold command, the autopilot's failsafe acts."""
        _signal(self.procs[uav_id].proc, signal.SIGKILL)

    def retire(self, uav_id: int) -> None:
        """Ask one agent to stop and leave its vehicle to the autopilot (SIGUSR1): its UAV is
        out of the mission after an autopilot fault, its companion computer is not dead."""
        _signal(self.procs[uav_id].proc, signal.SIGUSR1)

    async def stop(self, grace_s: float = 5.0) -> None:
        live = [ap.proc for ap in self.procs.values() if ap.proc.returncode is None]
        for p in live:
            _signal(p, signal.SIGTERM)
        for p in live:
            try:
                async with asyncio.timeout(grace_s):
                    await p.wait()
            except TimeoutError:
                _signal(p, signal.SIGKILL)
                await p.wait()

    async def __aenter__(self) -> AgentFleet:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()
