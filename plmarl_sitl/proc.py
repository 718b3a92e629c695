"""Child-process lifetime on Linux: a child asks the kernel to end it with its parent.

Used by everything the launcher starts (agents, forked or exec'd, and broker children),
so that no process outlives the launcher, even when it is SIGKILLed. Best effort where
prctl is unavailable (not Linux)."""

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


def set_process_name(name: str) -> None:
    """What ps, top and psutil's name() show (15 bytes at most)."""
    _prctl(15, name.encode()[:15])  # PR_SET_NAME
