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
"""

from __future__ import annotations

import argparse
import asyncio
import base64
import contextlib
import functools
import json
import os
import shutil
import signal
import socket
import sys
import tempfile
from pathlib import Path, PurePosixPath

from plmarl_sitl.proc import agent_child_setup

BUNDLE = "%BUNDLE%"
STOP_GRACE_S = 5.0
REACH_TIMEOUT_S = 5.0
LINE_LIMIT = 64 << 20  # a policy file travels base64 in one line
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
        self.agents: dict[int, asyncio.subprocess.Process] = {}
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
        argv = [a.replace(BUNDLE, str(self.bundle)) for a in argv]
        (self.bundle / "out").mkdir(mode=0o700, exist_ok=True)
        env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", PYTHONUNBUFFERED="1")
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "plmarl_sitl.cli", "agent", *argv, stdin=asyncio.subprocess.DEVNULL,
            stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT, cwd=self.bundle, env=env,
            preexec_fn=functools.partial(agent_child_setup, nice), limit=LINE_LIMIT)
        self.agents[uav] = proc
        self.say(op="started", uav=uav, pid=proc.pid)
        self.tasks.append(asyncio.create_task(self.follow(uav, proc, outputs)))

    async def follow(self, uav: int, proc: asyncio.subprocess.Process, outputs: dict[str, str]) -> None:
        """Forward the agent's output line by line; at its exit, its output files, then its code."""
        assert proc.stdout is not None
        while line := await proc.stdout.readline():
            self.say(op="log", uav=uav, text=line.decode(errors="replace").rstrip("\n"))
        code = await proc.wait()
        for key, rel in outputs.items():
            with contextlib.suppress(OSError, ValueError):
                self.say(op="file", uav=uav, key=key, data=base64.b64encode(self.inside(rel).read_bytes()).decode())
        self.say(op="exit", uav=uav, code=code)

    def signal(self, uav: int, sig: int) -> None:
        proc = self.agents.get(uav)
        if proc is not None and proc.returncode is None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(proc.pid, sig)

    async def handle(self, msg: dict) -> None:
        op = msg.get("op")
        if op == "file":
            self.write_file(str(msg["path"]), str(msg["data"]))
        elif op == "start":
            await self.start(int(msg["uav"]), [str(a) for a in msg["argv"]], dict(msg.get("outputs", {})),
                             int(msg.get("nice", 0)))
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
                await self.handle(json.loads(line))
        finally:
            self.stopping.set()

    # ------------------------------------------------------------------ stop
    async def stop_agents(self) -> None:
        live = [p for p in self.agents.values() if p.returncode is None]
        for p in live:
            with contextlib.suppress(ProcessLookupError):
                p.send_signal(signal.SIGTERM)
        for p in live:
            try:
                async with asyncio.timeout(STOP_GRACE_S):
                    await p.wait()
            except TimeoutError:
                with contextlib.suppress(ProcessLookupError):
                    p.kill()
                await p.wait()
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
