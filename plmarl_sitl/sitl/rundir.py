"""A run folder belongs to one run at a time, and a run starts only where it can record.

Why: two `swarm up` runs given the same `--out` truncated each other's metrics.jsonl and
both crashed at the end (`JSONDecodeError: Extra data`) with no summary; a full disk
showed a 60-line "Logging error" traceback after 83 s. The launcher claims the folder
with an exclusive `flock` on `RUN_LOCK` (released by the kernel when the process ends, a
SIGKILLed one included, so a stale lock never blocks the next run) and checks the disk
before it writes anything.
"""

from __future__ import annotations

import fcntl
import os
import shutil
from pathlib import Path
from typing import IO

from plmarl_sitl.errors import UserError

RUN_LOCK = ".run.lock"
MIN_FREE_BYTES = 64 << 20  # a 200-s run of 20 UAVs records ~20 MB (tlogs, metrics, agent logs)


def claim_run_dir(out: Path) -> IO[str]:
    """Create `out` if needed and lock it for this process; the returned file holds the lock
    until it is closed or the process ends. UserError (one line) when `out` is a file, is
    being recorded by another run, or its disk has less than MIN_FREE_BYTES free."""
    if out.exists() and not out.is_dir():
        raise UserError(f"--out {out}: exists and is not a directory")
    try:
        out.mkdir(parents=True, exist_ok=True)
        lock = open(out / RUN_LOCK, "a+")  # noqa: SIM115 - held open: the lock lives as long as the file
    except OSError as exc:
        raise UserError(f"--out {out}: cannot create the run folder ({exc.strerror})") from None
    try:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        lock.seek(0)
        owner = lock.read().strip() or "?"
        lock.close()
        raise UserError(f"--out {out}: another run (pid {owner}) is recording there; give this one another --out") from None
    free = shutil.disk_usage(out).free
    if free < MIN_FREE_BYTES:
        lock.close()
        raise UserError(f"--out {out}: only {free >> 20} MB free on its disk; a run needs at least {MIN_FREE_BYTES >> 20} MB")
    lock.seek(0)
    lock.truncate()
    lock.write(f"{os.getpid()}\n")
    lock.flush()
    return lock
