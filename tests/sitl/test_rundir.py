"""A run folder is one run's (issue 27, part 2): a second run on the same --out, an --out that
is a file, or a full disk is one line and exit 2 before anything starts; a SIGKILLed
launcher's broker scratch folder (password hashes, ACL) is removed by the next broker."""

import contextlib
import io
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import psutil
import pytest

from plmarl_sitl.cli import main
from plmarl_sitl.errors import UserError
from plmarl_sitl.sitl.network.broker import WORKDIR_PREFIX, remove_stale_workdirs
from plmarl_sitl.sitl.rundir import RUN_LOCK, claim_run_dir

ROOT = Path(__file__).resolve().parents[2]
MISSION = str(ROOT / "missions/paper_urban.yaml")


def _swarm_up(out: Path) -> tuple[int, str]:
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = main(["swarm", "up", MISSION, "--headless", "--out", str(out)])
    return code, err.getvalue()


def _holder(out: Path) -> subprocess.Popen:
    """Another process that claims `out` as a launcher does, then sleeps."""
    code = ("import sys, time; from pathlib import Path; from plmarl_sitl.sitl.rundir import claim_run_dir; "
            "lock = claim_run_dir(Path(sys.argv[1])); print('held', flush=True); time.sleep(60)")
    proc = subprocess.Popen([sys.executable, "-c", code, str(out)], stdout=subprocess.PIPE, text=True, cwd=ROOT)
    assert proc.stdout.readline().strip() == "held"
    return proc


def test_second_run_on_the_same_out_is_one_line(tmp_path):
    out = tmp_path / "run"
    holder = _holder(out)
    try:
        code, err = _swarm_up(out)
        assert code == 2 and err.count("\n") == 1, err
        assert f"another run (pid {holder.pid}) is recording there" in err
        assert sorted(os.listdir(out)) == [RUN_LOCK]  # nothing of the first run was touched
    finally:
        holder.kill()
        holder.wait()
    claim_run_dir(out).close()  # the kernel released the SIGKILLed holder's lock


def test_out_that_is_a_file(tmp_path):
    f = tmp_path / "notadir"
    f.write_text("x")
    code, err = _swarm_up(f)
    assert code == 2 and "exists and is not a directory" in err and err.count("\n") == 1


def test_full_disk_is_refused_at_once(tmp_path):
    mnt = tmp_path / "small"
    mnt.mkdir()
    if subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(mnt)], capture_output=True).returncode != 0:
        pytest.skip("cannot mount a 1 MB tmpfs here (needs root and mount rights)")
    try:
        t0 = time.monotonic()
        with pytest.raises(UserError, match=r"only 1 MB free on its disk; a run needs at least 64 MB"):
            claim_run_dir(mnt / "run")
        code, err = _swarm_up(mnt / "run2")
        assert code == 2 and err.count("\n") == 1 and "MB free" in err
        assert time.monotonic() - t0 < 10
    finally:
        subprocess.run(["umount", str(mnt)], check=False)


def test_sigkilled_owners_broker_folder_is_removed(tmp_path):
    code = ("import time; from plmarl_sitl.sitl.network.broker import MosquittoBroker; "
            "m = MosquittoBroker(); m.start(); print(m._dir.name, m.proc.pid, flush=True); time.sleep(60)")
    owner = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, cwd=ROOT)
    name, broker_pid = owner.stdout.readline().split()
    workdir = Path(name)
    assert workdir.name.startswith(f"{WORKDIR_PREFIX}mosquitto-{owner.pid}-") and workdir.is_dir()
    assert workdir not in remove_stale_workdirs()  # its owner lives
    os.kill(owner.pid, signal.SIGKILL)
    owner.wait()
    assert workdir.is_dir()  # a SIGKILLed owner cannot clean up ...
    assert workdir in remove_stale_workdirs()  # ... the next broker's start does
    assert not workdir.exists()
    assert not any(Path(tempfile.gettempdir()).glob(f"{WORKDIR_PREFIX}*-{owner.pid}-*"))
    # ... and the broker itself dies with its owner (as root it dropped privileges, which
    # cleared its parent-death signal, and outlived every SIGKILLed owner).
    deadline = time.time() + 10
    while psutil.pid_exists(int(broker_pid)) and psutil.Process(int(broker_pid)).status() != psutil.STATUS_ZOMBIE:
        assert time.time() < deadline, "the owner's mosquitto outlived it"
        time.sleep(0.1)
