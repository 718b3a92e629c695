"""The companion computer's end of a swarm spread over hosts: `python3 -m plmarl_sitl.deploy.companion`.

A launcher (`plmarl swarm up --hosts`, `sitl/remote.py`) runs this program on another
machine through a command prefix (`ssh user@host`, or `ip netns exec NS` in the tests)
and speaks to it over the prefix's stdin and stdout only, one JSON object a line. So
nothing needs to be copied to the host beforehand and no daemon runs there: what it needs
is Python with plmarl_sitl installed. The keys, logins, mission and policy travel through
stdin into a fresh private directory (0700, files 0600) that is deleted at exit.

    launcher -> host   {"op": "file", "path": REL, "data": BASE64}      a file of the bundle
                       {"op": "start", "uav": I, "argv": [...], "outputs": {KEY: REL}, "nice": N}
                           `plmarl agent ARGV` ("%BUNDLE%" in ARGV is the bundle directory)
                       {"op": "signal", "uav": I, "sig": N}             e.g. SIGKILL for a node failure
                       {"op": "ping"}                                    the launcher is there (each second)
                       {"op": "stop"}, or end of file                    stop every agent, then exit
    host -> launcher   {"op": "hello", "pid", "python", "source"}     once the broker answered from here
                       {"op": "started", "uav", "pid"}, {"op": "log", "uav", "text"},
                       {"op": "file", "uav", "key", "data"} (its outputs), then {"op": "exit", "uav", "code"}
                       {"op": "error", "text"}: one line, then exit 1 (e.g. the broker cannot be reached)

Lifetime: the agents stop (SIGTERM, then SIGKILL after STOP_GRACE_S) when the launcher
says so, when stdin ends (the launcher, or the SSH connection carrying it, is gone), when
nothing came down stdin for `--fence` seconds (a cut link: a TCP connection whose other
end went silent can stay open for hours), on SIGTERM or SIGHUP, and when stdout breaks; each agent also has PR_SET_PDEATHSIG, so a
SIGKILLed companion takes its agents along. No process is left on the host.

The agents are forked from one forkserver per host that imported torch and the agent
once (`deploy/companion_child.py`, as `sitl/forked.py` does for a launcher's local
agents): a host with several agents pays that start-up once and shares the pages. Each is
still `plmarl agent ARGV`, named plmarl-agentI in ps; its output goes to a file in the
bundle that the companion forwards line by line.
"""

from __future__ import annotations

import argparse
import asyncio
import base64
import contextlib
import json
import multiprocessing
import os
import shutil
import signal
import socket
import sys
import tempfile
from pathlib import Path, PurePosixPath

from plmarl_sitl.deploy.companion_child import PRELOAD, run_agent
from plmarl_sitl.proc import die_with_parent

BUNDLE = "%BUNDLE%"
STOP_GRACE_S = 5.0
REACH_TIMEOUT_S = 5.0
LINE_LIMIT = 64 << 20  # a policy file travels base64 in one line
LOG_POLL_S = 0.1  # how often an agent's new output is forwarded
# Output waiting for a launcher that does not read (a cut link: the SSH connection's buffers
# are full) is dropped past this, rather than block the companion and, behind it, its agents.
OUT_BACKLOG = 4 << 20


class _Upstream(asyncio.Protocol):
    """stdout as a non-blocking pipe; its end means the launcher is gone."""

    def __init__(self, gone: asyncio.Event) -> None:
        self.gone = gone

    def connection_lost(self, exc: Exception | None) -> None:
        self.gone.set()


class Companion:
    def __init__(self, name: str, bundle: Path, fence_s: float | None = None) -> None:
        self.name = name
        self.bundle = bundle
        self.fence_s = fence_s
        self.forks: multiprocessing.context.ForkServerContext | None = None  # at the first agent
        self.agents: dict[int, multiprocessing.process.BaseProcess] = {}
        self.tasks: list[asyncio.Task] = []
        self.stopping = asyncio.Event()
        self.out: asyncio.WriteTransport | None = None  # stdout, once the event loop runs
        self.dropped = 0  # output lines dropped for a launcher that did not read them

    # ------------------------------------------------------------------ to the launcher
    def say(self, **msg: object) -> None:
        line = json.dumps(msg).encode() + b"\n"
        if self.out is None:  # before the event loop: hello or error
            try:
                sys.stdout.buffer.write(line)
                sys.stdout.buffer.flush()
            except OSError:
                self.stopping.set()
        elif self.out.is_closing():
            self.stopping.set()  # nobody listens any more: stop
        elif self.out.get_write_buffer_size() > OUT_BACKLOG:
            self.dropped += 1
        else:
            self.out.write(line)

    # ------------------------------------------------------------------ from the launcher
    def inside(self, rel: str) -> Path:
        p = PurePosixPath(rel)
        if p.is_absolute() or ".." in p.parts or not p.parts:
            raise ValueError(f"bad bundle path {rel!r}")
        return self.bundle.joinpath(*p.parts)

    def write_file(self, rel: str, data: str) -> None:
        path = self.inside(rel)
        path.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "wb") as f:
            f.write(base64.b64decode(data))

    async def start(self, uav: int, argv: list[str], outputs: dict[str, str], nice: int) -> None:
        if self.forks is None:
            self.forks = multiprocessing.get_context("forkserver")
            self.forks.set_forkserver_preload(PRELOAD)
        argv = [a.replace(BUNDLE, str(self.bundle)) for a in argv]
        (self.bundle / "out").mkdir(mode=0o700, exist_ok=True)
        log_path = self.bundle / "out" / f"agent{uav}.log"
        proc = self.forks.Process(target=run_agent, name=f"plmarl-agent{uav}",
                                  args=(argv, str(log_path), str(self.bundle), nice, os.getpid(), f"plmarl-agent{uav}"))
        # The first start launches the forkserver, which imports torch: in a thread, so that
        # the commands (and the pings) keep being read meanwhile.
        await asyncio.get_running_loop().run_in_executor(None, proc.start)
        self.agents[uav] = proc
        self.say(op="started", uav=uav, pid=proc.pid)
        self.tasks.append(asyncio.create_task(self.follow(uav, proc, log_path, outputs)))

    async def follow(self, uav: int, proc: multiprocessing.process.BaseProcess, log_path: Path,
                     outputs: dict[str, str]) -> None:
        """Forward the agent's output line by line; at its exit, its output files, then its code."""
        pending, offset = b"", 0
        while True:
            done = proc.exitcode is not None
            with contextlib.suppress(FileNotFoundError):
                with open(log_path, "rb") as f:
                    f.seek(offset)
                    chunk = f.read()
                offset += len(chunk)
                *lines, pending = (pending + chunk).split(b"\n")
                for line in lines:
                    self.say(op="log", uav=uav, text=line.decode(errors="replace"))
            if done:
                break
            await asyncio.sleep(LOG_POLL_S)
        if pending:
            self.say(op="log", uav=uav, text=pending.decode(errors="replace"))
        code = proc.exitcode
        for key, rel in outputs.items():
            with contextlib.suppress(OSError, ValueError):
                self.say(op="file", uav=uav, key=key, data=base64.b64encode(self.inside(rel).read_bytes()).decode())
        self.say(op="exit", uav=uav, code=code)

    def signal(self, uav: int, sig: int) -> None:
        proc = self.agents.get(uav)
        if proc is not None and proc.pid is not None and proc.exitcode is None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(proc.pid, sig)

    async def handle(self, msg: dict) -> None:
        op = msg.get("op")
        if op == "file":
            self.write_file(str(msg["path"]), str(msg["data"]))
        elif op == "start":
            uav = int(msg["uav"])
            try:
                await self.start(uav, [str(a) for a in msg["argv"]], dict(msg.get("outputs", {})), int(msg.get("nice", 0)))
            except (OSError, ImportError, RuntimeError) as exc:  # e.g. torch missing on this host
                self.say(op="log", uav=uav, text=f"plmarl-companion {self.name}: cannot start the agent: {exc}")
                self.say(op="exit", uav=uav, code=1)
        elif op == "signal":
            self.signal(int(msg["uav"]), int(msg["sig"]))
        elif op == "stop":
            self.stopping.set()
        elif op != "ping":
            raise ValueError(f"unknown op {op!r}")

    async def read_commands(self) -> None:
        loop = asyncio.get_running_loop()
        reader = asyncio.StreamReader(limit=LINE_LIMIT)
        await loop.connect_read_pipe(lambda: asyncio.StreamReaderProtocol(reader), sys.stdin)
        try:
            while not self.stopping.is_set():
                try:
                    async with asyncio.timeout(self.fence_s):
                        line = await reader.readline()
                except TimeoutError:
                    print(f"plmarl-companion {self.name}: no word from the launcher for {self.fence_s:g} s: "
                          "stopping the agents", file=sys.stderr, flush=True)
                    break
                if not line:  # the launcher (or the connection carrying it) is gone
                    break
                try:
                    await self.handle(json.loads(line))
                except (ValueError, KeyError, TypeError) as exc:  # counted as dropped, as any bad input
                    print(f"plmarl-companion {self.name}: bad command dropped ({exc}): {line[:120]!r}",
                          file=sys.stderr, flush=True)
        finally:
            self.stopping.set()

    # ------------------------------------------------------------------ stop
    async def stop_agents(self) -> None:
        live = [u for u, p in self.agents.items() if p.exitcode is None]
        for u in live:
            self.signal(u, signal.SIGTERM)
        for u in live:
            if not await _exited(self.agents[u], STOP_GRACE_S):
                self.signal(u, signal.SIGKILL)
                await _exited(self.agents[u], STOP_GRACE_S)
        with contextlib.suppress(TimeoutError):
            async with asyncio.timeout(STOP_GRACE_S):
                await asyncio.gather(*self.tasks, return_exceptions=True)

    async def run(self) -> int:
        loop = asyncio.get_running_loop()
        for sig in (signal.SIGTERM, signal.SIGHUP):
            loop.add_signal_handler(sig, self.stopping.set)
        self.out, _ = await loop.connect_write_pipe(lambda: _Upstream(self.stopping), sys.stdout)
        reader = asyncio.create_task(self.read_commands())
        try:
            await self.stopping.wait()
        finally:
            reader.cancel()
            await self.stop_agents()
            if self.dropped:
                print(f"plmarl-companion {self.name}: {self.dropped} output lines dropped (the launcher did not read them)",
                      file=sys.stderr, flush=True)
            if not self.out.is_closing():
                with contextlib.suppress(TimeoutError):  # the last lines (exit codes, traces) out first
                    async with asyncio.timeout(STOP_GRACE_S):
                        while self.out.get_write_buffer_size() and not self.out.is_closing():
                            await asyncio.sleep(0.02)
        return 0


async def _exited(proc: multiprocessing.process.BaseProcess, timeout_s: float) -> bool:
    """Whether the forked process has exited within `timeout_s` (its exit code is polled)."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout_s
    while proc.exitcode is None and loop.time() < deadline:
        await asyncio.sleep(0.05)
    return proc.exitcode is not None


def reach(target: str) -> str:
    """Connect to the broker at HOST:PORT from here; our source address (what the launcher
    sees us as). Raises OSError, said in one line by the caller."""
    host, _, port = target.rpartition(":")
    with socket.create_connection((host.strip("[]"), int(port)), timeout=REACH_TIMEOUT_S) as s:
        return str(s.getsockname()[0])


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="plmarl-companion", description=__doc__.splitlines()[0])
    p.add_argument("--name", required=True, help="this host's name in the hosts file")
    p.add_argument("--reach", required=True, metavar="HOST:PORT", help="the swarm's broker, checked before anything starts")
    p.add_argument("--fence", type=float, default=None, metavar="S",
                   help="stop the agents and exit when the launcher has said nothing for S seconds (default: never)")
    args = p.parse_args(argv)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the launcher stops us (a terminal's Ctrl-C is its)
    die_with_parent()  # under `ip netns exec`, the launcher itself; under ssh, sshd's session
    # The forkserver inherits these before it imports torch (one BLAS thread per agent).
    os.environ.update(OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", PYTHONUNBUFFERED="1")
    bundle = Path(tempfile.mkdtemp(prefix=f"plmarl-{args.name}-"))  # 0700
    companion = Companion(args.name, bundle, args.fence)
    try:
        try:
            source = reach(args.reach)
        except (OSError, ValueError) as exc:
            why = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc) or exc.__class__.__name__
            companion.say(op="error", text=f"cannot reach the broker at {args.reach} from here: {why}")
            return 1
        companion.say(op="hello", pid=os.getpid(), python=sys.executable, source=source)
        return asyncio.run(companion.run())
    finally:
        shutil.rmtree(bundle, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
