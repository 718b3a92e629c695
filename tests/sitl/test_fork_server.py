"""The agents' fork server (sitl/forked.py, sitl/forked_child.py): forked from a launcher that
runs one thread (one `import torch` for the whole rig, issue 25.1), exec'd from one that runs
threads; either way it forks real `plmarl agent` processes and reports their exit codes."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest

ROOT = Path(__file__).resolve().parents[2]

# A launcher in miniature: start the server (after a thread, when asked), fork three agents
# (--help: exit 0; a bad --id: exit 2; one that waits for a vehicle that never answers, then
# SIGKILLed) and print what it saw.
LAUNCHER = r"""
import asyncio, json, os, signal, sys, threading, time
import psutil
if sys.argv[2] == "threads":
    threading.Thread(target=time.sleep, args=(30,), daemon=True).start()
from plmarl_sitl.sitl import forked
server = forked.start_server()
out = sys.argv[1]

async def main():
    a = await forked.fork_agent(["--help"], f"{out}/help.log", {"PLMARL_X": "1"}, name="plmarl-agent0")
    b = await forked.fork_agent(["--id", "x"], f"{out}/bad.log", {}, name="plmarl-agent1")
    c = await forked.fork_agent(["--id", "0", "--connect", "udpout://127.0.0.1:9", "--broker", "mqtt://127.0.0.1:9",
                                 "--no-auth"], f"{out}/wait.log", {}, name="plmarl-agent2", nice=3)
    await asyncio.sleep(0.5)
    srv = psutil.Process(server.pid)
    seen = {"server_ppid": srv.ppid(), "server_cmdline": srv.cmdline(), "server_name": srv.name(),
            "launcher_cmdline": psutil.Process().cmdline(), "c_ppid": psutil.Process(c.pid).ppid(),
            "c_name": psutil.Process(c.pid).name(), "c_nice": psutil.Process(c.pid).nice()}
    c.kill()
    seen["codes"] = [await p.wait() for p in (a, b, c)]
    print(json.dumps(seen))

asyncio.run(main())
forked.stop_server()
"""


@pytest.mark.parametrize("kind", ["fork", "threads"])
def test_the_server_forks_agents_and_reports_their_exits(tmp_path, kind):
    r = subprocess.run([sys.executable, "-c", LAUNCHER, str(tmp_path), kind], capture_output=True, text=True, timeout=120,
                       cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert r.returncode == 0, r.stderr[-3000:]
    seen = json.loads(r.stdout.strip().splitlines()[-1])
    assert seen["codes"] == [0, 2, -signal.SIGKILL]
    assert seen["server_name"] == "plmarl-forksrv"
    assert seen["c_name"] == "plmarl-agent2" and seen["c_nice"] >= 3
    if kind == "fork":
        # Forked from the launcher: its command line, no interpreter of its own (no second `import torch`).
        assert seen["server_cmdline"] == seen["launcher_cmdline"]
    else:
        assert "plmarl_sitl.sitl.forked_child" in seen["server_cmdline"]
    assert "usage: plmarl agent" in (tmp_path / "help.log").read_text()
    assert "--id" in (tmp_path / "bad.log").read_text()


def test_swarm_up_forks_its_server_before_the_world_loads(tmp_path):
    """`plmarl swarm up`: the server is the launcher's child with the launcher's command line
    (forked after `import torch`, before any thread), every agent is the server's child, and the
    launcher, SIGKILLed, leaves neither behind."""
    out = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-m", "plmarl_sitl.cli", "swarm", "up", str(ROOT / "missions" / "paper_urban.yaml"),
                             "--speedup", "5", "--headless", "--out", str(out)], cwd=ROOT, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        launcher = psutil.Process(proc.pid)
        deadline = time.time() + 120
        agents: list[psutil.Process] = []
        while time.time() < deadline and len(agents) < 4:
            children = launcher.children(recursive=True)
            agents = [c for c in children if c.name().startswith("plmarl-agent")]
            time.sleep(0.5)
        assert len(agents) == 4
        servers = [c for c in launcher.children() if c.name() == "plmarl-forksrv"]
        assert len(servers) == 1 and servers[0].cmdline() == launcher.cmdline()
        assert {a.ppid() for a in agents} == {servers[0].pid}
        proc.kill()
        proc.wait(timeout=10)
        gone, alive = psutil.wait_procs(children, timeout=15)
        assert not alive, [c.name() for c in alive]
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
