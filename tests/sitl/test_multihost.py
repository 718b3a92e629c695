"""`plmarl swarm up --hosts`: a swarm spread over three hosts, each a network namespace.

The fixture makes three namespaces on this machine: `g` (the launcher's host: the
launcher, the world and mosquitto) holds a bridge with 10.231.25.1/24; `a` (10.231.25.2)
and `b` (10.231.25.3) are joined to it by veth links. Every packet between an agent and
the world or the broker crosses a veth link and the bridge: the launcher's address is
not on a loopback interface of the agents' namespaces, and nothing listens on 127.0.0.1.
The hosts file reaches a and b with `ip netns exec NS` as its command prefix (what `ssh
user@host` is on a real cluster). The addresses are private test addresses that exist
only inside these namespaces.
"""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = [pytest.mark.integration, pytest.mark.slow]  # whole SITL swarms over namespaces, 5-30 s each
ROOT = Path(__file__).resolve().parents[2]
SUBNET = "10.231.25"
LAUNCHER, HOST_A, HOST_B = f"{SUBNET}.1", f"{SUBNET}.2", f"{SUBNET}.3"


def _ip(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    return subprocess.run(["ip", *args], capture_output=True, text=True, check=check)


def _pids(ns: str) -> list[int]:
    r = _ip("netns", "pids", ns, check=False)
    return [int(x) for x in r.stdout.split()]


class Namespaces:
    def __init__(self, prefix: str) -> None:
        self.g, self.a, self.b = f"{prefix}g", f"{prefix}a", f"{prefix}b"
        self.all = (self.g, self.a, self.b)

    def create(self) -> None:
        for ns in self.all:
            _ip("netns", "add", ns)
            _ip("-n", ns, "link", "set", "lo", "up")
        _ip("-n", self.g, "link", "add", "br0", "type", "bridge")
        _ip("-n", self.g, "addr", "add", f"{LAUNCHER}/24", "dev", "br0")
        _ip("-n", self.g, "link", "set", "br0", "up")
        for ns, addr, port in ((self.a, HOST_A, "va"), (self.b, HOST_B, "vb")):
            _ip("link", "add", port, "netns", self.g, "type", "veth", "peer", "name", "eth0", "netns", ns)
            _ip("-n", self.g, "link", "set", port, "master", "br0")
            _ip("-n", self.g, "link", "set", port, "up")
            _ip("-n", ns, "addr", "add", f"{addr}/24", "dev", "eth0")
            _ip("-n", ns, "link", "set", "eth0", "up")

    def cut(self, ns: str) -> None:
        """The host's link goes down: it can reach nobody and nobody reaches it."""
        _ip("-n", ns, "link", "set", "eth0", "down")

    def leftovers(self) -> dict[str, list[str]]:
        out = {}
        for ns in self.all:
            names = []
            for pid in _pids(ns):
                try:
                    names.append(Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()[:120])
                except OSError:
                    continue  # exited meanwhile
            if names:
                out[ns] = names
        return out

    def destroy(self) -> None:
        for ns in self.all:
            for pid in _pids(ns):  # processes this test started there (a failed test's leftovers)
                try:
                    os.kill(pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
            _ip("netns", "del", ns, check=False)


def _netns_permitted() -> str | None:
    if shutil.which("ip") is None:
        return "the `ip` command (iproute2) is not installed"
    probe = f"plmprobe{os.getpid()}"
    r = _ip("netns", "add", probe, check=False)
    if r.returncode != 0:
        return f"`ip netns add` is not permitted here: {r.stderr.strip()}"
    _ip("netns", "del", probe, check=False)
    return None


@pytest.fixture
def ns():
    why = _netns_permitted()
    if why is not None:
        pytest.skip(why)
    spaces = Namespaces(f"plm{os.getpid() % 100000}")
    try:
        spaces.create()
        yield spaces
    finally:
        spaces.destroy()


def _mission(tmp_path: Path, events: str = "[]") -> Path:
    p = tmp_path / "mission.yaml"
    p.write_text(f"extends: {ROOT / 'missions' / 'paper_urban.yaml'}\nname: multihost\nevents: {events}\n")
    return p


def _hosts(tmp_path: Path, ns: Namespaces, *, b_run: list[str] | None = None, extra: str = "") -> Path:
    p = tmp_path / "hosts.yaml"
    py = sys.executable
    b_run = b_run or ["ip", "netns", "exec", ns.b]
    p.write_text(f"launcher: {{address: {LAUNCHER}}}\n{extra}hosts:\n"
                 f"  - {{name: a, run: [ip, netns, exec, {ns.a}], address: {HOST_A}, uavs: [0, 1], python: {py}}}\n"
                 f"  - {{name: b, run: {json.dumps(b_run)}, address: {HOST_B}, uavs: [2, 3], python: {py}}}\n")
    return p


def _up_cmd(ns: Namespaces, mission: Path, hosts: Path, out: Path, duration: int, *extra: str) -> list[str]:
    return ["ip", "netns", "exec", ns.g, sys.executable, "-m", "plmarl_sitl.cli", "swarm", "up", str(mission),
            "--hosts", str(hosts), "--broker", "mosquitto", "--lockstep", "--duration", str(duration),
            "--out", str(out), "--headless", *extra]


def _rows(out: Path) -> list[dict]:
    path = out / "metrics.jsonl"
    return [json.loads(x) for x in path.read_text().splitlines()] if path.exists() else []


def _events(out: Path) -> list[dict]:
    return [json.loads(x) for x in (out / "events.jsonl").read_text().splitlines()]


def _wait_rows(proc: subprocess.Popen, out: Path, rows: int, timeout_s: float = 120) -> None:
    deadline = time.time() + timeout_s
    while time.time() < deadline:
        if len(_rows(out)) >= rows:
            return
        assert proc.poll() is None, proc.communicate()[1][-2000:]
        time.sleep(0.05)
    raise AssertionError(f"fewer than {rows} metrics rows after {timeout_s} s")


def _no_leftovers(ns: Namespaces, within_s: float = 10.0) -> None:
    deadline = time.time() + within_s
    while ns.leftovers() and time.time() < deadline:
        time.sleep(0.1)
    assert not ns.leftovers(), ns.leftovers()


def test_a_mission_over_three_hosts_completes(ns, tmp_path):
    out = tmp_path / "run"
    r = subprocess.run(_up_cmd(ns, _mission(tmp_path), _hosts(tmp_path, ns), out, 20, "--json"),
                       capture_output=True, text=True, timeout=180, cwd=ROOT)
    assert r.returncode == 0, r.stderr[-2000:] + (out / "launcher.log").read_text()[-2000:]
    summary = json.loads(r.stdout.strip().splitlines()[-1])
    rows = _rows(out)
    assert [row["t"] for row in rows] == list(range(21))
    assert all(u["alive"] and -u["pos_ned"][2] > 30 for u in rows[-1]["uavs"]), "every vehicle flies its mission"
    assert rows[-1]["coverage"] > 0.5 and sum(row["messages"] for row in rows) > 0  # signalling crossed the hosts
    assert summary["events"] == [] and summary["timeliness"]["decisions"] > 0  # the traces came back
    log = (out / "launcher.log").read_text()
    # Each host reached the broker from its own address on the veth link: no loopback.
    assert f"host a ({HOST_A}) flies UAVs 0, 1" in log and f"host b ({HOST_B}) flies UAVs 2, 3" in log
    for i, host in ((0, "a"), (1, "a"), (2, "b"), (3, "b")):
        agent_log = (out / "agents" / f"agent{i}.log").read_text()
        assert f"on host {host}" in agent_log.splitlines()[0]
        assert f"udpout://{LAUNCHER}:" in agent_log and "in OFFBOARD" in agent_log  # flew its vehicle over the link
        assert (out / "agents" / f"agent{i}.trace.jsonl").stat().st_size > 0
    # Signed and logged in as before: no vehicle saw unsigned or badly signed input.
    assert all(v["unsigned"] == 0 and v["bad_signature"] == 0 for v in summary["vehicle_input"])
    _no_leftovers(ns)


def test_ctrl_c_on_the_launcher_leaves_no_process_on_any_host(ns, tmp_path):
    out = tmp_path / "run"
    proc = subprocess.Popen(_up_cmd(ns, _mission(tmp_path), _hosts(tmp_path, ns), out, 600), cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        _wait_rows(proc, out, 3)
        assert _pids(ns.a) and _pids(ns.b), "agents run on both hosts"
        os.killpg(proc.pid, signal.SIGINT)  # what a terminal's Ctrl-C sends to the launcher's group
        _, stderr = proc.communicate(timeout=60)
        assert proc.returncode == 130, stderr[-2000:]
        _no_leftovers(ns)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)


def test_a_host_cut_off_mid_mission_is_node_failures(ns, tmp_path):
    out = tmp_path / "run"
    hosts = _hosts(tmp_path, ns, extra="silence_s: 2\n")
    proc = subprocess.Popen(_up_cmd(ns, _mission(tmp_path), hosts, out, 40, "--json"), cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        _wait_rows(proc, out, 8)
        ns.cut(ns.b)
        stdout, stderr = proc.communicate(timeout=120)
        assert proc.returncode == 0, stderr[-2000:]
        failures = [e for e in _events(out) if e["type"] == "node_failure"]
        assert [(e["uav"], e["cause"], e["host"]) for e in failures] == [(2, "host_lost", "b"), (3, "host_lost", "b")]
        assert 7 <= failures[0]["t"] <= 20
        summary = json.loads(stdout.strip().splitlines()[-1])
        assert [f["at_s"] for f in summary["node_failures"]] == [failures[0]["t"]] * 2
        rows = _rows(out)
        assert rows[-1]["t"] == 40  # the mission went on with host a
        assert [u["alive"] for u in rows[-1]["uavs"]] == [True, True, False, False]
        _no_leftovers(ns)  # b's agents were killed through its command channel, not left flying blind
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)


@pytest.mark.parametrize("case", ["prefix fails", "link down", "no answer"])
def test_a_host_unreachable_at_start_is_one_line(ns, tmp_path, case):
    out = tmp_path / "run"
    b_run = {"prefix fails": ["ip", "netns", "exec", f"{ns.b}-missing"], "link down": None,
             "no answer": ["ip", "netns", "exec", ns.b, "sh", "-c", "sleep 600", "sh"]}[case]
    hosts = _hosts(tmp_path, ns, b_run=b_run, extra="connect_timeout_s: 3\n")
    if case == "link down":
        ns.cut(ns.b)
    t0 = time.time()
    r = subprocess.run(_up_cmd(ns, _mission(tmp_path), hosts, out, 20), capture_output=True, text=True, timeout=120,
                       cwd=ROOT)
    assert r.returncode == 1
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("plmarl swarm up: failed: host b"), r.stderr
    expected = {"prefix fails": "Cannot open network namespace", "link down": f"cannot reach the broker at {LAUNCHER}:",
                "no answer": "did not answer within 3 s"}[case]
    assert expected in lines[0]
    assert time.time() - t0 < 60
    _no_leftovers(ns)
