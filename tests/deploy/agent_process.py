"""`plmarl agent` as a child process, its stderr read line by line: what a user sees."""

from __future__ import annotations

import asyncio
import contextlib
import os
import signal
import sys
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass
from pathlib import Path

import pytest

from plmarl_sitl.mission import Origin
from plmarl_sitl.sitl.autopilot import AutopilotHost, run_realtime
from plmarl_sitl.sitl.network.broker import free_udp_ports

ROOT = Path(__file__).resolve().parents[2]


@dataclass
class AgentRun:
    code: int
    err: str

    def errors(self) -> list[str]:
        """The lines that report the failure (`plmarl agent: error: ...`)."""
        return [x for x in self.err.splitlines() if x.startswith("plmarl agent: error:")]


async def run_agent(argv: list[str], *, cwd: Path = ROOT, timeout_s: float = 90.0,
                    on_line: Callable[[str], bool | None] | None = None,
                    interrupt_when: Callable[[], bool] | None = None, sig: signal.Signals = signal.SIGINT,
                    repeat_every_s: float | None = None) -> AgentRun:
    """Run `plmarl agent ARGV` until it exits. `on_line(line)` sees each stderr line;
    returning True sends `sig` (default SIGINT, Ctrl-C), as does `interrupt_when()` turning
    True (polled every 0.2 s): once, or from then on every `repeat_every_s` until it exits."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])))
    proc = await asyncio.create_subprocess_exec(sys.executable, "-m", "plmarl_sitl.cli", "agent", *argv, cwd=cwd, env=env,
                                                stdout=asyncio.subprocess.DEVNULL, stderr=asyncio.subprocess.PIPE)
    assert proc.stderr is not None
    lines: list[str] = []
    interrupted = False

    def signal_agent() -> None:
        # os.kill, not proc.send_signal: Popen.send_signal polls first, and that waitpid can
        # reap the child before asyncio's child watcher does, which then reports exit 255
        # ("Unknown child process") instead of the agent's own code.
        with contextlib.suppress(ProcessLookupError):
            os.kill(proc.pid, sig)

    def interrupt() -> None:
        nonlocal interrupted
        if not interrupted and proc.returncode is None:
            signal_agent()
            interrupted = True

    async def poll() -> None:
        while interrupt_when is not None and not interrupted:
            if interrupt_when():
                interrupt()
            await asyncio.sleep(0.2)
        while repeat_every_s is not None and proc.returncode is None:
            if interrupted:
                signal_agent()
            await asyncio.sleep(repeat_every_s)

    poller = asyncio.create_task(poll())
    try:
        async with asyncio.timeout(timeout_s):
            while line := (await proc.stderr.readline()).decode():
                lines.append(line)
                if on_line is not None and on_line(line):
                    interrupt()
            await proc.wait()
    except TimeoutError:
        pytest.fail(f"the agent did not end within {timeout_s:g} s:\n{''.join(lines)}")
    finally:
        poller.cancel()
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
    assert proc.returncode is not None
    return AgentRun(proc.returncode, "".join(lines))


def stop_at(needle: str) -> Callable[[str], bool]:
    return lambda line: needle in line


@contextlib.asynccontextmanager
async def emulated_vehicle(personality: str = "ardupilot", speedup: float = 20.0, origin: Origin | None = None,
                           **kwargs: object) -> AsyncIterator[AutopilotHost]:
    """One emulated autopilot on a free UDP port, clocked at `speedup` until the block ends."""
    host = AutopilotHost(1, personality_name=personality, base_port=free_udp_ports(1), origin=origin, **kwargs)  # type: ignore[arg-type]
    await host.start()
    stop = asyncio.Event()
    clock = asyncio.create_task(run_realtime(host, speedup, stop=stop, log_every_s=1e9), name="autopilot-clock")
    try:
        yield host
    finally:
        stop.set()
        await clock
        host.close()


def agent_argv(port_or_url: int | str, broker: str = "mqtt://127.0.0.1:1", *extra: str) -> list[str]:
    """One agent of a one-UAV mission on the emulator port (or a URL); with no broker the
    bus retries in the background and nothing else notices."""
    url = port_or_url if isinstance(port_or_url, str) else f"udpout://127.0.0.1:{port_or_url}"
    return ["--id", "0", "--n-uavs", "1", "--connect", url, "--broker", broker, "--no-auth", *extra]
