"""Agent processes forked from one interpreter that has already imported torch.

`import torch` costs ~1.2 s of CPU per process. Twenty agents exec'd at once on two cores
spend ~15 s of wall time importing the same modules before any vehicle flies. A swarm
launcher therefore starts one multiprocessing *forkserver* that preloads the agent's
imports once, and forks each agent from it (copy-on-write, ~20 ms each). Each child is
still one asyncio process per UAV running `plmarl agent` with the same arguments; only
the interpreter start-up is shared. A companion computer runs `plmarl agent` itself.

Lifetime: no agent outlives the launcher, even a SIGKILLed one. Each child gets SIGTERM
(its normal stop: the vehicle to its stop mode, exit) when the launcher exits, through a
pidfd of the launcher (`proc.sigterm_when_gone`), and when the forkserver dies
(PR_SET_PDEATHSIG). The forkserver exits when its "alive" pipe from the launcher has no
writer left; but multiprocessing hands every forked child a copy of that pipe's write
end, so the forkserver outlives the launcher until its children are gone. Waiting for
the forkserver alone therefore left the agents running until their own start-up waits
timed out (30-120 s); watching the launcher itself does not depend on that pipe.
"""

from __future__ import annotations

import asyncio
import json
import multiprocessing
import os
import signal
import sys
from multiprocessing.context import ForkServerContext

import psutil

from plmarl_sitl.proc import agent_child_setup, output_to, set_process_name, sigterm_when_gone

# What the forkserver imports once; a forked agent finds these already in sys.modules.
PRELOAD = ["plmarl_sitl.sitl.forked_child"]

_context: ForkServerContext | None = None


def context() -> ForkServerContext:
    global _context
    if _context is None:
        ctx = multiprocessing.get_context("forkserver")
        ctx.set_forkserver_preload(PRELOAD)
        _context = ctx
    return _context


PRELOAD_ENV = "PLMARL_AGENT_PRELOAD"  # read by forked_child: {"policy": DIR, "mission": FILE} to load before forking


def warm_up(policy: str | os.PathLike | None = None, mission: str | os.PathLike | None = None) -> None:
    """Start the forkserver now: it imports torch in its own process, on another core,
    while the caller starts the broker and the world. With `policy` and `mission` it also
    loads that policy and builds its plan grid, once for every agent it forks
    (deploy/agent/preload.py). A forkserver already running keeps what it loaded."""
    import multiprocessing.forkserver

    context()
    saved = os.environ.get(PRELOAD_ENV)
    if policy is not None and mission is not None:
        os.environ[PRELOAD_ENV] = json.dumps({"policy": str(policy), "mission": str(mission)})
    try:
        multiprocessing.forkserver.ensure_running()  # the server inherits the environment now
    finally:
        if saved is None:
            os.environ.pop(PRELOAD_ENV, None)
        else:
            os.environ[PRELOAD_ENV] = saved


def run_agent(argv: list[str], log_path: str, env: dict[str, str], name: str, nice: int, launcher: int) -> None:
    """The child: stdout/stderr to `log_path`, then `plmarl agent ARGV`; exit with its code.
    `name` (e.g. plmarl-agent3) is what ps, top and psutil's name() show for it; `nice`
    is added to its niceness. It stops (SIGTERM) when process `launcher` exits."""
    agent_child_setup(nice)
    sigterm_when_gone(launcher)  # first, before anything slow (see Lifetime above)
    if not _forkserver_parent_is(launcher):
        # The launcher died before the pidfd was opened: its pid may name another process by now.
        os.kill(os.getpid(), signal.SIGTERM)
    set_process_name(name)  # the command line is the forkserver's
    output_to(log_path, 0o644)
    os.environ.update(env)
    from plmarl_sitl.deploy.agent.program import main

    sys.exit(main(argv))


def _forkserver_parent_is(pid: int) -> bool:
    """Whether this child's forkserver is still the child of process `pid` (it is
    reparented once the launcher that started it is gone)."""
    try:
        return psutil.Process(os.getppid()).ppid() == pid
    except psutil.Error:
        return False


class ForkedProcess:
    """The part of `asyncio.subprocess.Process` the fleet uses, for a forked agent."""

    def __init__(self, proc: multiprocessing.process.BaseProcess) -> None:
        self._proc = proc
        self.pid = proc.pid

    @property
    def returncode(self) -> int | None:
        """Exit code, or -signal when a signal killed it (as asyncio reports it)."""
        return self._proc.exitcode

    async def wait(self) -> int:
        while self._proc.exitcode is None:
            await asyncio.sleep(0.05)
        return self._proc.exitcode

    def send_signal(self, sig: int) -> None:
        if self._proc.exitcode is None:
            os.kill(self.pid, sig)  # type: ignore[arg-type]

    def terminate(self) -> None:
        self.send_signal(signal.SIGTERM)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)


async def fork_agent(argv: list[str], log_path: str, env: dict[str, str], name: str, nice: int = 0) -> ForkedProcess:
    """Fork `plmarl agent ARGV` from the preloaded forkserver (started on first use; its
    imports run in a thread so the caller's event loop keeps serving the vehicles)."""
    proc = context().Process(target=run_agent, args=(argv, log_path, env, name, nice, os.getpid()), name=name)
    await asyncio.get_running_loop().run_in_executor(None, proc.start)
    return ForkedProcess(proc)
