"""The fleet signals its exec'd agents without reaping them behind asyncio's back.

asyncio's `Process.send_signal` and `kill` are `Popen.send_signal`, which polls first: when
the agent has just exited, that waitpid reaps it before asyncio's child watcher does, and
the watcher then reports exit 255 ("Unknown child process") instead of the agent's code.
The window is made deterministic here: a child watcher that reaps from the event loop
(asyncio's PidfdChildWatcher, a real one) and `os.waitid(..., WNOWAIT)`, which waits for the
child to exit and leaves it unreaped, so every signal below reaches an exited, unreaped child.
"""

from __future__ import annotations

import asyncio
import os
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from plmarl_sitl.sitl.agents import AgentFleet, AgentProc

EXIT_CODE = 3


def _exit_code_after(tmp_path: Path, signal_it: Callable[[AgentFleet], object]) -> int:
    async def main() -> int:
        fleet = AgentFleet(tmp_path)
        proc = await asyncio.create_subprocess_exec(sys.executable, "-c", f"raise SystemExit({EXIT_CODE})")
        fleet.procs[0] = AgentProc(0, proc, tmp_path / "agent0.log", None, None)
        os.waitid(os.P_PID, proc.pid, os.WEXITED | os.WNOWAIT)  # exited, not reaped; the loop has not run since
        assert proc.returncode is None
        done = signal_it(fleet)
        if asyncio.iscoroutine(done):
            await done
        return await proc.wait()

    watcher = asyncio.PidfdChildWatcher()
    asyncio.set_child_watcher(watcher)
    try:
        return asyncio.run(main())
    finally:
        asyncio.set_child_watcher(None)  # back to the default (a ThreadedChildWatcher made on demand)


@pytest.mark.skipif(not hasattr(os, "pidfd_open"), reason="needs pidfd_open (Linux >= 5.3)")
@pytest.mark.parametrize("how", ["stop", "retire", "kill"])
def test_signalling_an_agent_that_just_exited_keeps_its_exit_code(tmp_path: Path, how: str) -> None:
    signal_it = {"stop": lambda f: f.stop(grace_s=5.0), "retire": lambda f: f.retire(0), "kill": lambda f: f.kill(0)}[how]
    assert _exit_code_after(tmp_path, signal_it) == EXIT_CODE
