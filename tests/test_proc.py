"""`proc.sigterm_when_gone`: a process watched by pid ends this one, as a parent's death does
with PR_SET_PDEATHSIG (what keeps a forked agent from outliving a SIGKILLed launcher)."""

import signal
import subprocess
import sys
import time

# The watcher: SIGTERM (default action: die) once process argv[1] is gone; prints "watching" first.
WATCHER = """
import sys, time
from plmarl_sitl.proc import sigterm_when_gone
assert sigterm_when_gone(int(sys.argv[1]))
print("watching", flush=True)
time.sleep(60)
"""


def _watch(pid: int) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", WATCHER, str(pid)], stdout=subprocess.PIPE, text=True)


def test_sigterm_when_the_watched_process_is_killed():
    target = subprocess.Popen(["sleep", "60"])
    watcher = _watch(target.pid)
    try:
        assert watcher.stdout.readline() == "watching\n"
        assert watcher.poll() is None
        target.kill()  # SIGKILL: nothing the target runs can warn anyone
        t0 = time.monotonic()
        assert watcher.wait(timeout=10) == -signal.SIGTERM
        assert time.monotonic() - t0 < 2
    finally:
        target.kill()
        watcher.kill()


def test_sigterm_at_once_when_the_process_is_gone_already():
    target = subprocess.Popen(["true"])
    target.wait()  # reaped: no such pid any more
    watcher = _watch(target.pid)
    try:
        assert watcher.wait(timeout=10) == -signal.SIGTERM
        assert watcher.stdout.read() == ""
    finally:
        watcher.kill()
