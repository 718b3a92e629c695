"""Process lifetime and scheduling on Linux.

- A child asks the kernel to end it with its parent: used by everything the launcher
  starts (agents, forked or exec'd, and broker children), so that no process outlives
  the launcher, even when it is SIGKILLed (best effort where prctl is unavailable).
  A child whose parent is not the process it must die with (a forked agent's parent is
  the forkserver) also watches that process (`sigterm_when_gone`).
- An agent may lower its priority (SITL) or run under SCHED_FIFO (a companion computer)."""

from __future__ import annotations

import signal


def _prctl(option: int, arg: int | bytes) -> None:
    try:
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(option, arg)
    except (OSError, AttributeError):  # not Linux: best effort
        pass


def die_with_parent() -> None:
    """Ask Linux to SIGTERM this process when its parent dies, even by SIGKILL (as a
    `preexec_fn`, or first thing in a forked child)."""
    _prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG


def sigterm_when_gone(pid: int) -> bool:
    """SIGTERM this process when process `pid` exits, even by SIGKILL, as PR_SET_PDEATHSIG
    does for a parent: a daemon thread waits on a pidfd (Linux >= 5.3) of `pid`; at once if
    `pid` is gone already. Returns False where pidfds are unavailable (then nothing
    watches). Call it after any fork: a forked child has no copy of the thread."""
    import os
    import select
    import threading

    try:
        pidfd = os.pidfd_open(pid)
    except ProcessLookupError:
        os.kill(os.getpid(), signal.SIGTERM)
        return True
    except (AttributeError, OSError):  # not Linux, or a kernel before 5.3: best effort
        return False

    def watch() -> None:
        select.select([pidfd], [], [])  # readable once `pid` has exited
        os.kill(os.getpid(), signal.SIGTERM)

    threading.Thread(target=watch, name=f"sigterm-when-{pid}-gone", daemon=True).start()
    return True


def agent_child_setup(nice: int = 0) -> None:
    """First thing in an agent child, exec'd (`preexec_fn`) or forked: die with the
    parent, then add `nice` to its niceness."""
    die_with_parent()
    if nice:
        import os

        os.nice(nice)


def output_to(log_path: str, mode: int) -> None:
    """A child agent's stdout and stderr to the file `log_path` (created with `mode`,
    truncated), line-buffered so its log can be followed while it runs."""
    import os
    import sys

    fd = os.open(log_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, mode)
    os.dup2(fd, 1)
    os.dup2(fd, 2)
    os.close(fd)
    sys.stdout.reconfigure(line_buffering=True)  # type: ignore[union-attr]
    sys.stderr.reconfigure(line_buffering=True)  # type: ignore[union-attr]


def set_process_name(name: str) -> None:
    """What ps, top and psutil's name() show (15 bytes at most)."""
    _prctl(15, name.encode()[:15])  # PR_SET_NAME


RT_HOWTO = (
    "SCHED_FIFO needs CAP_SYS_NICE: run as root, `sudo setcap cap_sys_nice+ep $(readlink -f $(which python3))`, "
    "or allow it in /etc/security/limits.conf (`USER - rtprio 20`)"
)


def realtime_permitted(priority: int) -> bool:
    """Whether this process may switch itself to SCHED_FIFO at `priority` (CAP_SYS_NICE,
    or an RLIMIT_RTPRIO at least that high)."""
    import resource

    try:
        soft, _ = resource.getrlimit(resource.RLIMIT_RTPRIO)
        if soft == resource.RLIM_INFINITY or soft >= priority:
            return True
        with open("/proc/self/status") as f:
            cap_eff = next(int(line.split()[1], 16) for line in f if line.startswith("CapEff:"))
        return bool(cap_eff >> 23 & 1)  # CAP_SYS_NICE
    except (OSError, StopIteration, ValueError, AttributeError):
        return False


def use_realtime(priority: int) -> None:
    """Run this process's threads (this one and those it starts later) under SCHED_FIFO
    at `priority` (1-99), as PX4 runs its own tasks on Linux and as a companion computer
    should run a control loop: nothing at normal priority then preempts it mid-decision.
    The kernel's RT throttling (95 % of each second by default) still bounds a runaway.
    Raises UserError, saying how to allow it, when the process may not."""
    import os

    from plmarl_sitl.errors import UserError

    if not 1 <= priority <= 99:
        raise UserError(f"real-time priority {priority}: must be 1-99")
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except PermissionError as exc:
        raise UserError(f"cannot use real-time priority {priority}: {RT_HOWTO}") from exc
