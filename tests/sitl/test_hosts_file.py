"""The hosts file of `plmarl swarm up --hosts` (strict, like a mission), the host-loss rule,
and the companion process driven through a command prefix on this machine (`env`, which
runs the rest of its command line here: what `ssh user@host` does there)."""

import asyncio
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from plmarl_sitl.config import ConfigError
from plmarl_sitl.sitl.hosts import load_hosts
from plmarl_sitl.sitl.remote import HostFailed, RemoteHost, RemoteHosts

ROOT = Path(__file__).resolve().parents[2]
GOOD = """\
launcher: {address: 127.0.0.1}
silence_s: 2
hosts:
  - {name: cc-a, run: [ssh, -o, BatchMode=yes, pi@cc-a], address: 10.0.0.2, uavs: [0, 1]}
  - {name: cc-b, run: [ssh, pi@cc-b], address: 10.0.0.3, uavs: [3], python: /opt/plmarl/bin/python}
"""


def _file(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "hosts.yaml"
    p.write_text(text)
    return p


def test_a_good_hosts_file_places_uavs(tmp_path):
    hosts = load_hosts(_file(tmp_path, GOOD), 4)
    assert [h.name for h in hosts.hosts] == ["cc-a", "cc-b"]
    assert hosts.host_of(1).name == "cc-a" and hosts.host_of(3).python == "/opt/plmarl/bin/python"
    assert hosts.host_of(2) is None  # runs on the launcher's host
    assert hosts.hosts[0].run == ("ssh", "-o", "BatchMode=yes", "pi@cc-a") and hosts.silence_s == 2


@pytest.mark.parametrize(("text", "n", "says"), [
    (GOOD.replace("uavs: [3]", "uavz: [3]"), 4, "hosts[1].uavz: unknown key"),
    (GOOD.replace("uavs: [3]", "uavs: [x]"), 4, "hosts[1].uavs[0]: expected an integer"),
    (GOOD.replace("uavs: [3]", "uavs: [1]"), 4, "hosts[1].uavs: UAV 1 is placed on 'cc-a' already"),
    (GOOD, 3, "hosts[1].uavs[0]: UAV 3: the mission has UAVs 0-2"),
    (GOOD.replace("run: [ssh, pi@cc-b]", "run: []"), 4, "hosts[1].run: a command prefix"),
    (GOOD.replace("name: cc-b", "name: cc-a"), 4, "hosts[1].name: 'cc-a' is used twice"),
    (GOOD.replace("/opt/plmarl/bin/python", "'python3; rm -rf x'"), 4, "hosts[1].python: a path without spaces"),
    (GOOD.replace("launcher: {address: 127.0.0.1}", "launcher: {adress: 127.0.0.1}"), 4, "launcher.adress: unknown key"),
    # 192.0.2.1 is TEST-NET-1 (RFC 5737): never an address of this machine; only bind() is tried.
    (GOOD.replace("address: 127.0.0.1", "address: 192.0.2.1"), 4, "launcher.address: 192.0.2.1 is not an address of this machine"),
    (GOOD.replace("silence_s: 2", "silence_s: 0.5"), 4, "silence_s: must be >= 1.5"),
])
def test_a_wrong_hosts_file_names_the_key(tmp_path, text, n, says):
    path = _file(tmp_path, text)
    with pytest.raises(ConfigError) as err:
        load_hosts(path, n)
    assert str(err.value).startswith(f"{path}: ") and says in str(err.value)


def test_swarm_up_with_a_wrong_hosts_file_exits_2_in_one_line(tmp_path):
    path = _file(tmp_path, GOOD.replace("uavs: [3]", "uavz: [3]"))
    r = subprocess.run([sys.executable, "-m", "plmarl_sitl.cli", "swarm", "up", str(ROOT / "missions" / "paper_urban.yaml"),
                        "--hosts", str(path), "--out", str(tmp_path / "run"), "--headless"],
                       capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [f"plmarl swarm: error: {path}: hosts[1].uavz: unknown key "
                                             "(allowed: address, name, python, run, uavs)"]
    assert not (tmp_path / "run").exists()  # nothing started


def test_a_host_is_lost_when_none_of_its_agents_is_heard(tmp_path):
    remote = RemoteHosts(load_hosts(_file(tmp_path, GOOD), 4), tmp_path)
    counts = [10, 10, 10, 10]
    assert remote.lost(counts, set(), 0.0) == []
    counts[0] += 1  # one agent of cc-a still talks: cc-a is not lost
    assert remote.lost(counts, set(), 1.9) == []
    assert [h.name for h in remote.lost(counts, set(), 2.1)] == ["cc-b"]  # silent since 0.0
    assert remote.lost(counts, set(), 3.0) == []  # declared once
    assert [h.name for h in remote.lost(counts, set(), 4.0)] == ["cc-a"]  # silent since 1.9
    # A host whose agents are all out of the mission anyway is not watched.
    remote = RemoteHosts(load_hosts(_file(tmp_path, GOOD), 4), tmp_path)
    assert remote.lost(counts, {3}, 0.0) == [] and [h.name for h in remote.lost(counts, {3}, 9.0)] == ["cc-a"]


def _local_host(tmp_path: Path, run: list[str]) -> RemoteHost:
    text = GOOD.replace("run: [ssh, -o, BatchMode=yes, pi@cc-a]", f"run: {run}").replace(
        "uavs: [0, 1]}", f"uavs: [0, 1], python: {sys.executable}}}")
    return RemoteHosts(load_hosts(_file(tmp_path, text), 4), tmp_path / "hosts").hosts[0]


def test_the_companion_answers_once_it_reaches_the_broker_and_exits_when_closed(tmp_path):
    async def main() -> None:
        with socket.socket() as listener:
            listener.bind(("127.0.0.1", 0))
            listener.listen()
            host = _local_host(tmp_path, ["env"])
            source = await host.connect(f"127.0.0.1:{listener.getsockname()[1]}", 20)
            assert source == "127.0.0.1"
            await host.close()
            assert host.proc is not None and host.proc.returncode == 0

    asyncio.run(main())


def test_a_companion_that_cannot_reach_the_broker_says_so(tmp_path):
    async def main() -> None:
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]  # bound, not listening: refused
            host = _local_host(tmp_path, ["env"])
            with pytest.raises(HostFailed, match=rf"host cc-a: cannot reach the broker at 127.0.0.1:{port} from here: "
                                                 "Connection refused"):
                await host.connect(f"127.0.0.1:{port}", 20)
            await host.close()

    asyncio.run(main())


def test_the_companion_writes_bundle_files_privately_and_only_inside_its_directory(tmp_path):
    from plmarl_sitl.deploy.companion import Companion

    bundle = tmp_path / "bundle"
    bundle.mkdir(mode=0o700)
    c = Companion("cc-a", bundle)
    c.write_file("keys/swarm.key", "YWJj")  # base64 of "abc"
    key = bundle / "keys" / "swarm.key"
    assert key.read_bytes() == b"abc" and key.stat().st_mode & 0o777 == 0o600
    assert (bundle / "keys").stat().st_mode & 0o777 == 0o700
    for bad in ("../escape", "/etc/passwd", "keys/../../escape", ""):
        with pytest.raises(ValueError):
            c.write_file(bad, "YWJj")
    assert not (tmp_path / "escape").exists()
