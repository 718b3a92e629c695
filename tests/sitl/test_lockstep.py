"""`plmarl swarm up --lockstep` end to end: deterministic outputs under CPU load, a stopped
agent declared failed while the mission goes on. (Ctrl-C in lockstep: test_swarm_up.py's
Ctrl-C test, run for both paces.)"""

import hashlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest

from plmarl_sitl.bench.swarm import answered_share

pytestmark = [pytest.mark.integration, pytest.mark.slow]  # whole SITL swarms, 20-90 s each
ROOT = Path(__file__).resolve().parents[2]

# Scripted events early in a short mission: a link blackout, T_up 15 -> 5, a node failure
# and a broker outage over a signalling instant (lockstep emulates it in the world).
EVENTS = ("  - {type: link_blackout, at_s: 6, duration_s: 5, uavs: [0]}\n"
          "  - {type: tup_change, at_s: 10, tup_s: 5}\n"
          "  - {type: node_failure, at_s: 14, uav: 2}\n"
          "  - {type: broker_outage, at_s: 15, duration_s: 5}\n")


def _mission(tmp_path: Path) -> Path:
    p = tmp_path / "lockstep.yaml"
    p.write_text(f"extends: {ROOT / 'missions' / 'paper_urban.yaml'}\nname: lockstep\nevents:\n{EVENTS}")
    return p


def _cmd(mission: Path, out: Path, duration: int, *extra: str) -> list[str]:
    return [sys.executable, "-m", "plmarl_sitl.cli", "swarm", "up", str(mission), "--lockstep", "--speedup", "10",
            "--duration", str(duration), "--out", str(out), "--headless", *extra]


def _digest(out: Path) -> dict[str, str]:
    """Hashes of the run's outputs; the summary without its run directory (a path)."""
    summary = json.loads((out / "summary.json").read_text())
    summary.pop("run_dir")
    return {
        "metrics": hashlib.sha256((out / "metrics.jsonl").read_bytes()).hexdigest(),
        "events": hashlib.sha256((out / "events.jsonl").read_bytes()).hexdigest(),
        "summary": hashlib.sha256(json.dumps(summary, sort_keys=True).encode()).hexdigest(),
    }


def _hogs(n: int) -> list[subprocess.Popen]:
    return [subprocess.Popen([sys.executable, "-c", "while 1: pass"]) for _ in range(n)]


def test_same_seed_same_outputs_with_a_cpu_hog_beside_one_run(tmp_path):
    mission = _mission(tmp_path)
    digests = []
    for run, hogs in (("quiet", 0), ("loaded", 2)):
        out = tmp_path / run
        procs = _hogs(hogs)
        try:
            r = subprocess.run(_cmd(mission, out, 25, "--json"), capture_output=True, text=True, timeout=300, cwd=ROOT)
        finally:
            for p in procs:
                p.kill()
                p.wait()
        assert r.returncode == 0, r.stderr[-2000:]
        # --headless says what start-up waits for (the take-off takes ~40 vehicle s), not only the mission's lines.
        assert "start-up, 10 s: waiting for 4 of 4 vehicles to fly under their agents" in r.stdout, r.stdout[:2000]
        digests.append(_digest(out))
        flown = json.loads(r.stdout.strip().splitlines()[-1])  # wall-clock figures: printed, not in summary.json
        assert flown["achieved_speedup"] == pytest.approx(25 / flown["mission_wall_s"])
        assert "mission_wall_s" not in json.loads((out / "summary.json").read_text())
    rows = [json.loads(x) for x in (tmp_path / "quiet" / "metrics.jsonl").read_text().splitlines()]
    assert [r["t"] for r in rows] == list(range(26))
    events = [json.loads(x)["type"] for x in (tmp_path / "quiet" / "events.jsonl").read_text().splitlines()]
    assert events == ["link_blackout", "tup_change", "node_failure", "broker_outage", "broker_outage_end"]
    # States go out at the instants 0, then (T_up 5 from t = 11 on) 15, 20 and 25, each
    # counted in the next second's row; the outage swallowed those of t = 15.
    assert [r["t"] for r in rows if r["messages"]] == [1, 21], [r["messages"] for r in rows]
    assert digests[0] == digests[1]
    # Lockstep answers every telemetry sample (what `plmarl bench swarm` reports as "answered").
    assert answered_share(tmp_path / "quiet") == pytest.approx(1.0, abs=0.05)


def _wait_rows(proc: subprocess.Popen, out: Path, rows: int, timeout_s: float = 180) -> None:
    deadline = time.time() + timeout_s
    while time.time() < deadline:
        if (out / "metrics.jsonl").exists() and (out / "metrics.jsonl").read_text().count("\n") >= rows:
            return
        assert proc.poll() is None, proc.stderr.read().decode()[-2000:]
        time.sleep(0.05)
    raise AssertionError(f"fewer than {rows} metrics rows after {timeout_s} s")


def _agents(proc: subprocess.Popen) -> dict[int, psutil.Process]:
    children = psutil.Process(proc.pid).children(recursive=True)
    return {int(c.name().removeprefix("plmarl-agent")): c for c in children if c.name().startswith("plmarl-agent")}


def test_a_stopped_agent_is_declared_failed_and_the_mission_completes(tmp_path):
    mission = ROOT / "missions" / "paper_urban.yaml"
    out = tmp_path / "run"
    proc = subprocess.Popen(_cmd(mission, out, 30, "--straggler", "2", "--json"), cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, start_new_session=True)
    try:
        _wait_rows(proc, out, 5)
        agents = _agents(proc)
        assert sorted(agents) == [0, 1, 2, 3]
        stopped_at = time.time()
        agents[1].send_signal(signal.SIGSTOP)
        stdout, stderr = proc.communicate(timeout=240)
        assert proc.returncode == 0, stderr.decode()[-2000:]
        summary = json.loads(stdout.decode().strip().splitlines()[-1])
        failed = [e for e in summary["events"] if e["type"] == "agent_failed"]
        assert [e["uav"] for e in failed] == [1] and "2 s" in failed[0]["why"]
        rows = [json.loads(x) for x in (out / "metrics.jsonl").read_text().splitlines()]
        assert rows[-1]["t"] == 30
        # Within the bound: the world waited about 2 s of wall time for it, not the whole run.
        log = (out / "launcher.log").read_text()
        assert "agent 1 declared failed" in log
        assert time.time() - stopped_at < 200
        # Its vehicle failed safe (PX4: no setpoints for COM_OF_LOSS_T -> AUTO.LOITER) and stays alive.
        assert "offboard setpoints lost" in log
        assert all(u["alive"] for u in rows[-1]["uavs"])
        gone, alive = psutil.wait_procs(list(agents.values()), timeout=15)
        assert not alive, [c.cmdline() for c in alive]
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
