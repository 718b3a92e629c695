"""`plmarl agent --rt-priority`: the agent runs under SCHED_FIFO where the process may
use it, and says how to allow it where it may not (exit 2, one line)."""

from __future__ import annotations

import os
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from plmarl_sitl.cli import main
from plmarl_sitl.proc import realtime_permitted

pytestmark = [pytest.mark.timeout(60), pytest.mark.integration]
ROOT = Path(__file__).resolve().parents[2]
# Nothing listens on these: the agent sets its priority, then waits for a heartbeat.
AGENT = [sys.executable, "-m", "plmarl_sitl.cli", "agent", "--id", "0", "--connect", "udpout://127.0.0.1:9",
         "--broker", "mqtt://127.0.0.1:9", "--rt-priority", "7", "-v", "--no-auth"]


def _no_rtprio_rlimit() -> None:
    resource.setrlimit(resource.RLIMIT_RTPRIO, (0, 0))


def test_agent_runs_under_sched_fifo_or_says_how_to_allow_it(tmp_path: Path) -> None:
    log = tmp_path / "agent.log"
    with open(log, "wb") as out:
        proc = subprocess.Popen(AGENT, cwd=ROOT, stdout=out, stderr=subprocess.STDOUT)
    try:
        if not realtime_permitted(7):
            assert proc.wait(30) == 2
            assert "CAP_SYS_NICE" in log.read_text() and "Traceback" not in log.read_text()
            return
        deadline = time.monotonic() + 30
        while "running under SCHED_FIFO" not in log.read_text():
            assert proc.poll() is None, log.read_text()
            assert time.monotonic() < deadline, log.read_text()
            time.sleep(0.1)
        assert os.sched_getscheduler(proc.pid) == os.SCHED_FIFO
        assert os.sched_getparam(proc.pid).sched_priority == 7
    finally:
        proc.terminate()
        proc.wait(10)


@pytest.mark.skipif(realtime_permitted(7) and shutil.which("setpriv") is None,
                    reason="needs util-linux setpriv to drop CAP_SYS_NICE")
def test_without_cap_sys_nice_the_agent_exits_with_the_how_to() -> None:
    drop = ["setpriv", "--bounding-set=-sys_nice"] if realtime_permitted(7) else []
    r = subprocess.run([*drop, *AGENT], cwd=ROOT, capture_output=True, text=True, timeout=30, preexec_fn=_no_rtprio_rlimit)
    assert r.returncode == 2, r.stderr
    assert "cannot use real-time priority 7" in r.stderr and "CAP_SYS_NICE" in r.stderr
    assert "Traceback" not in r.stderr


@pytest.mark.parametrize("value,needle", [("0", "outside 1-99"), ("100", "outside 1-99"), ("high", "not a priority")])
def test_priority_out_of_range_is_an_argparse_error(value: str, needle: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["agent", "--id", "0", "--connect", "udpout://127.0.0.1:9", "--broker", "mqtt://127.0.0.1:9", "--rt-priority", value,
              "--no-auth"])
    assert exc.value.code == 2
    assert needle in capsys.readouterr().err
