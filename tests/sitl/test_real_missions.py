"""Whole missions on autopilots that are not the world's own (issue 13, deliverable 3).

* With ARDUCOPTER=/path/to/arducopter (a real ArduCopter SITL built from ArduPilot's
  source): `plmarl swarm up --autopilot arducopter=$ARDUCOPTER` flies a 2-UAV, 60 s
  mission on two real ArduCopters at speedup 5 end to end, and Ctrl-C mid-run leaves no
  process. Instances -I 60..69 (ports 6360..6453) so other tests' ArduCopters do not collide.
* Always: `plmarl world --external URL,URL` runs a mission on two emulated ArduPilot
  autopilots started as separate `plmarl autopilot` processes (real-timeline boot, each its
  own clock), each flown by a real `plmarl agent` process.

Everything runs under nice; timings are printed (pytest -s)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest
import real_autopilots
from real_autopilots import ROOT, cli, env, names, rows

from plmarl_sitl.deploy.mqtt.auth import create_key_file
from plmarl_sitl.mission import load_mission
from plmarl_sitl.sitl.arducopter import instance_free, launch_homes
from plmarl_sitl.sitl.network.broker import free_port, free_udp_ports

pytestmark = [pytest.mark.integration, pytest.mark.slow]
BINARY = os.environ.get("ARDUCOPTER", "")
needs_arducopter = pytest.mark.skipif(not BINARY, reason="set ARDUCOPTER=/path/to/arducopter (a real ArduCopter SITL "
                                      "binary built from ArduPilot's source) to run")
INSTANCES = range(60, 70)


def short_mission(tmp_path: Path, episode_s: int = 60) -> Path:
    """The paper mission with 2 UAVs and a short episode (T_up 15)."""
    p = tmp_path / "short2.yaml"
    p.write_text(f"extends: {ROOT / 'missions' / 'paper_urban.yaml'}\nname: short2\nn_uavs: 2\n"
                 "signalling: {tup_s: 15, buffer_len: 10, drop_after_missed: 2}\n"
                 f"timing: {{dt_s: 1, decision_every_s: 3, episode_s: {episode_s}}}\n")
    return p


def free_base(n: int) -> int:
    return real_autopilots.free_base(n, INSTANCES, instance_free, "ArduPilot SITL instances (-I)")


def trace(out: Path, i: int) -> list[dict]:
    return [json.loads(x) for x in (out / "agents" / f"agent{i}.trace.jsonl").read_text().splitlines() if x.strip()]


def descendants(pid: int) -> list[psutil.Process]:
    return psutil.Process(pid).children(recursive=True)


# ---------------------------------------------------------------------------- real ArduCopter
@needs_arducopter
@pytest.mark.timeout(400)
def test_a_short_mission_on_two_real_arducopters_completes(tmp_path: Path) -> None:
    mission, out = short_mission(tmp_path), tmp_path / "run"
    base = free_base(2)
    t0 = time.monotonic()
    proc = subprocess.Popen(cli("swarm", "up", str(mission), "--autopilot", f"arducopter={BINARY}", "--speedup", "5",
                                "--headless", "--json", "--instance", str(base), "--out", str(out)),
                            cwd=tmp_path, env=env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    seen: list[psutil.Process] = []
    kinds: set[str] = set()
    try:
        while proc.poll() is None and time.monotonic() - t0 < 360:  # everything it starts, while it runs
            try:
                new = [c for c in descendants(proc.pid) if c not in seen]
            except psutil.NoSuchProcess:
                break
            seen += new
            # Names read again each time: a forked agent renames itself (plmarl-agentN) a moment
            # after the fork, and a loaded machine can show it here in between as "python".
            kinds.update(names(seen))
            time.sleep(0.5)
        stdout, stderr = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    wall = time.monotonic() - t0
    log = (out / "launcher.log").read_text() if (out / "launcher.log").exists() else ""
    assert proc.returncode == 0, f"exit {proc.returncode}: {stderr[-2000:]}\n{log[-3000:]}"
    summary = json.loads(stdout.strip().splitlines()[-1])
    r = rows(out)
    print(f"\n2 real ArduCopters x5, 60 s mission: {wall:.1f} s wall, coverage mean {summary['coverage_mean']:.3f}, "
          f"final {r[-1]['coverage']:.3f}, timeliness {summary['timeliness']}")
    assert summary["autopilot"] == "arducopter"
    assert "agents on SERIAL0 tcp" in stdout + stderr  # the run says which ports
    # Coverage rows, one per mission second, from the real vehicles' reported positions:
    # both at the mission's 60 m take-off altitude at t = 0, over their launch slots.
    assert [x["t"] for x in r] == list(range(61))
    slots = launch_homes(load_mission(out / "mission.yaml"))
    assert len(slots) == 2
    for u in r[0]["uavs"]:
        assert u["alive"] and 55 <= -u["pos_ned"][2] <= 65, u
    assert all(0 <= x["coverage"] <= 1 for x in r) and max(x["coverage"] for x in r) > 0.2
    moved = [abs(a - b) for a, b in zip(r[0]["uavs"][0]["pos_ned"][:2], r[-1]["uavs"][0]["pos_ned"][:2], strict=True)]
    assert max(moved) > 10, (r[0]["uavs"][0], r[-1]["uavs"][0])  # the policy flew it
    # Both agents flew their vehicle: decisions every tau, stats written, GUIDED then BRAKE.
    for i in (0, 1):
        decided = [x for x in trace(out, i) if x.get("decided")]
        assert len(decided) >= 15, i
        assert (out / "agents" / f"agent{i}.stats.json").exists()
        agent_log = (out / "agents" / f"agent{i}.log").read_text()
        assert "in GUIDED at" in agent_log and "stopped: vehicle in BRAKE" in agent_log, agent_log
        assert " DEBUG " not in agent_log  # swarm agents are not verbose unless asked (-v)
        assert (out / "tlogs" / f"vehicle{i}.tlog").stat().st_size > 10_000
        assert (out / "arducopter" / f"vehicle{i}" / "eeprom.bin").exists()
    # The world followed the vehicles' clocks and gave each agent t0 on its own clock.
    assert "mission starts at boot" in log and "on each vehicle's clock" in log
    # No process left: the ArduCopters, the agents, the forkserver, the broker.
    assert {"arducopter", "plmarl-agent0", "plmarl-agent1"} <= kinds, kinds
    _, alive = psutil.wait_procs(seen, timeout=10)
    assert not alive, names(alive)


@needs_arducopter
@pytest.mark.timeout(300)
def test_ctrl_c_mid_mission_on_real_arducopters_leaves_no_process(tmp_path: Path) -> None:
    mission, out = short_mission(tmp_path, episode_s=200), tmp_path / "run"
    base = free_base(2)
    proc = subprocess.Popen(cli("swarm", "up", str(mission), "--autopilot", f"arducopter={BINARY}", "--speedup", "5",
                                "--headless", "--instance", str(base), "--out", str(out)),
                            cwd=tmp_path, env=env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True)
    launcher_pid = proc.pid
    try:
        deadline = time.monotonic() + 180
        while not ((out / "metrics.jsonl").exists() and (out / "metrics.jsonl").read_text().count("\n") >= 5):
            assert proc.poll() is None, proc.stderr.read().decode()[-2000:]  # type: ignore[union-attr]
            assert time.monotonic() < deadline, "the mission did not start in 180 s"
            time.sleep(0.5)
        # The launcher runs under nice: its children are its grandchildren here.
        children = descendants(launcher_pid)
        kinds = names(children)
        assert kinds.count("arducopter") == 2 and len([k for k in kinds if k.startswith("plmarl-agent")]) == 2, kinds
        t_int = time.monotonic()
        os.kill(launcher_pid, signal.SIGINT)  # the launcher alone: it must stop everything itself
        proc.wait(timeout=60)
        _, alive = psutil.wait_procs(children, timeout=15)
        took = time.monotonic() - t_int
        print(f"\nSIGINT mid-mission: launcher exit {proc.returncode}, all {len(children)} children gone {took:.1f} s later")
        assert proc.returncode == 130
        assert not alive, names(alive)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)


# ---------------------------------------------------------------------------- world --external
@pytest.mark.timeout(300)
def test_world_external_runs_a_mission_on_two_separate_autopilot_processes(tmp_path: Path) -> None:
    """Two `plmarl autopilot` processes (ArduPilot personality, real-timeline boot: each
    clock starts when its agent connects), two agents on them, and `plmarl world
    --external` on a second link to each: the mission runs its 40 s and ends."""
    mission = short_mission(tmp_path, episode_s=40)
    m = load_mission(mission)
    base = free_udp_ports(2)  # the first of two free consecutive ports
    ports = [base, base + 1]
    broker = f"mqtt://127.0.0.1:{free_port()}"
    started = real_autopilots.Started(tmp_path)
    start, logs = started.start, started.logs

    create_key_file(tmp_path / "swarm.key")
    t0 = time.monotonic()
    try:
        world = start(["world", str(mission), "--broker", broker, "--embedded-broker", "--speedup", "5", "--episode", "40",
                       "--swarm-key", "swarm.key",
                       "--external", ",".join(f"udpout://127.0.0.1:{p}" for p in ports), "--summary-json",
                       str(tmp_path / "world.json"), "-v"], "world")
        for i, (lat, lon, alt, _) in enumerate(launch_homes(m)):
            start(["autopilot", "--count", "1", "--personality", "ardupilot", "--boot", "real", "--speedup", "5",
                   "--base-port", str(ports[i]), "--home", f"{lat:.8f},{lon:.8f},{alt:.2f}"], f"autopilot{i}")
            start(["agent", "--id", str(i), "--connect", f"udpout://127.0.0.1:{ports[i]}", "--broker", broker,
                   "--mission", str(mission), "--autopilot", "ardupilot", "--swarm-key", "swarm.key"], f"agent{i}")
        world.wait(timeout=240)
        wall = time.monotonic() - t0
        assert world.returncode == 0, logs()
        out = json.loads((tmp_path / "world.json").read_text())
        print(f"\nworld --external on 2 emulated ArduPilots (real boot) x5, 40 s: {wall:.1f} s wall, "
              f"mean coverage {out['mean_coverage']:.3f}")
        assert out["mission_seconds"] == 40 and 0 < out["mean_coverage"] <= 1
        world_log = (tmp_path / "world.log").read_text()
        assert "vehicle 0: ardupilot autopilot" in world_log and "vehicle 1: ardupilot autopilot" in world_log
        assert "on each vehicle's clock" in world_log
        for i in (0, 1):
            agent_log = (tmp_path / f"agent{i}.log").read_text()
            assert "in GUIDED at" in agent_log and "mission clock: t0 = boot" in agent_log, agent_log
    finally:
        started.interrupt()


@needs_arducopter
@pytest.mark.timeout(500)
def test_autopilot_faults_on_four_real_arducopters_are_confirmed_in_the_recording(tmp_path: Path) -> None:
    """GPS loss (SIM_GPS1_ENABLE) and motor failure (SIM_ENGINE_FAIL) through ArduCopter's own
    fault injection: the same checks as the emulator's run (tests/sitl/test_swarm_up.py)."""
    sys.path.insert(0, str(Path(__file__).parent))
    from test_swarm_up import FAULTS, _agents_left_their_vehicles, _fault_checks

    mission = tmp_path / "faults.yaml"
    mission.write_text(f"extends: {ROOT / 'missions' / 'paper_urban.yaml'}\nname: faults\n"
                       f"timing: {{dt_s: 1, decision_every_s: 3, episode_s: 90}}\nevents:\n{FAULTS}")
    out, base = tmp_path / "run", free_base(4)
    r = subprocess.run(cli("swarm", "up", str(mission), "--autopilot", f"arducopter={BINARY}", "--speedup", "5",
                           "--headless", "--json", "--instance", str(base), "--out", str(out)),
                       cwd=tmp_path, env=env(), capture_output=True, text=True, timeout=480)
    log = (out / "launcher.log").read_text() if (out / "launcher.log").exists() else ""
    assert r.returncode == 0, f"exit {r.returncode}: {r.stderr[-2000:]}\n{log[-3000:]}"
    events = [json.loads(x) for x in (out / "events.jsonl").read_text().splitlines()]
    _fault_checks(events)
    _agents_left_their_vehicles(out)
