"""Faults in flight that must not lose the run (issue 27), free-running and in lockstep:
- an agent that dies (`kill -9`) is a node failure to record: the mission completes with its
  summary, `agent_failed` in events.jsonl, and the dead agent's vehicle fails safe;
- a broker that stalls (SIGSTOP for seconds, then SIGCONT) is recorded as `broker_lost` /
  `broker_back`, the vehicles' physics and telemetry go on, and the mission completes."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest

pytestmark = [pytest.mark.integration, pytest.mark.slow]
ROOT = Path(__file__).resolve().parents[2]


def _agents(proc: subprocess.Popen) -> dict[int, psutil.Process]:
    children = psutil.Process(proc.pid).children(recursive=True)
    return {int(c.name().removeprefix("plmarl-agent")): c for c in children if c.name().startswith("plmarl-agent")}


def _rows(out: Path) -> list[dict]:
    f = out / "metrics.jsonl"
    return [json.loads(x) for x in f.read_text().splitlines() if x.strip()] if f.exists() else []


@pytest.mark.parametrize("pace", [["--speedup", "10"], ["--lockstep", "--speedup", "10"]], ids=["free", "lockstep"])
def test_a_killed_agent_is_recorded_and_the_mission_completes(tmp_path, pace):
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "plmarl_sitl.cli", "swarm", "up", str(ROOT / "missions/paper_urban.yaml"), *pace,
           "--duration", "40", "--out", str(out), "--headless", "--json", "--seed", "0"]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
    try:
        deadline = time.time() + 180
        while time.time() < deadline and len(_rows(out)) < 10:  # mission second 10: in flight
            assert proc.poll() is None, proc.stderr.read().decode()[-2000:]
            time.sleep(0.1)
        agents = _agents(proc)
        assert sorted(agents) == [0, 1, 2, 3]
        agents[2].kill()
        stdout, stderr = proc.communicate(timeout=240)
        assert proc.returncode == 0, stderr.decode()[-2000:]
        summary = json.loads(stdout.decode().strip().splitlines()[-1])
        assert (out / "summary.json").exists()
        events = [json.loads(x) for x in (out / "events.jsonl").read_text().splitlines()]
        failed = [e for e in events if e["type"] == "agent_failed"]
        assert [e["uav"] for e in failed] == [2] and "killed" in failed[0]["why"], failed
        assert [e["uav"] for e in summary["events"] if e["type"] == "agent_failed"] == [2]
        assert _rows(out)[-1]["t"] == 40  # the whole mission
        assert "offboard setpoints lost" in (out / "launcher.log").read_text()  # its vehicle failed safe
        gone, alive = psutil.wait_procs(list(agents.values()), timeout=15)
        assert not alive
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)


STALL_S = 12  # wall seconds the broker is stopped for


def _broker_child(proc: subprocess.Popen, kind: str) -> psutil.Process:
    names = {"mosquitto": "mosquitto", "embedded": "amqtt_child"}
    for c in psutil.Process(proc.pid).children(recursive=True):
        # The agents' fork server and the agents are forked from the launcher: they carry its
        # command line (with "--broker mosquitto" in it) under their own names (plmarl-*)
        if not c.name().startswith("plmarl-") and names[kind] in " ".join(c.cmdline()):
            return c
    raise AssertionError(f"no {kind} broker child")


@pytest.mark.parametrize(("pace", "broker"), [(["--speedup", "5"], "mosquitto"), (["--speedup", "5"], "embedded"),
                                             (["--lockstep", "--speedup", "5"], "mosquitto")],
                         ids=["free-mosquitto", "free-embedded", "lockstep-mosquitto"])
def test_a_stalled_broker_is_recorded_and_the_mission_completes(tmp_path, pace, broker):
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "plmarl_sitl.cli", "swarm", "up", str(ROOT / "missions/paper_urban.yaml"), *pace,
           "--broker", broker, "--duration", "120", "--out", str(out), "--headless", "--json", "--seed", "0"]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
    try:
        deadline = time.time() + 180
        while time.time() < deadline and len(_rows(out)) < 20:
            assert proc.poll() is None, proc.stderr.read().decode()[-2000:]
            time.sleep(0.1)
        child = _broker_child(proc, broker)
        child.suspend()
        stalled_at = len(_rows(out))
        # Longer than the bus can take to notice: keepalive 5 s, and paho declares the link
        # dead only a keepalive after its unanswered ping, 5-10 s into the stall by the phase
        # it lands in (an 8 s stall was noticed or not as the start-up's length moved it).
        time.sleep(STALL_S)
        during = len(_rows(out)) - stalled_at
        child.resume()
        stdout, stderr = proc.communicate(timeout=240)
        assert proc.returncode == 0, stderr.decode()[-2000:]
        rows = _rows(out)
        assert rows[-1]["t"] == 120 and (out / "summary.json").exists()
        if "--lockstep" not in pace:
            assert during >= 10, f"the world made {during} mission seconds in {STALL_S} s of stall at 5x"
        log = (out / "launcher.log").read_text()
        # The defect fixed: a writer registered on a closed or reused descriptor (EBADF, a spinning loop).
        # (aiomqtt 2.5.1 may still log "Exception in callback" for a connect attempt cancelled while
        # the broker is stopped: harmless, noted in docs/RESULTS.md.)
        assert "Bad file descriptor" not in log
        types = [json.loads(x)["type"] for x in (out / "events.jsonl").read_text().splitlines()]
        if "--lockstep" not in pace:  # free-running: the world's bus notices the stall (keepalive 5 s)
            assert "broker_lost" in types and "broker_back" in types, types
        assert all(u["alive"] for u in rows[-1]["uavs"])
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
