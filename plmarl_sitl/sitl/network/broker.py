"""Brokers for tests, the world process and the launcher: embedded amqtt or a mosquitto child.

amqtt 0.12's `Broker(config_dict)` takes `listeners` and a `plugins` mapping; only the
anonymous-auth plugin is loaded (the default set adds $SYS publishing and packet logging,
which cost CPU for nothing here), or, with a `BrokerAccess` (`access.py`), its password
and topic-ACL plugins. A mosquitto child with a `BrokerAccess` gets a password file, an
ACL file, no anonymous clients, and each client's username as its client id (a login
cannot take over another client's session by reusing its id).
"""

from __future__ import annotations

import asyncio
import contextlib
import getpass
import json
import logging
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import AsyncIterator
from pathlib import Path

from plmarl_sitl.proc import die_with_parent
from plmarl_sitl.sitl.network.access import BrokerAccess

MOSQUITTO = shutil.which("mosquitto") or "/usr/sbin/mosquitto"


def free_port(host: str = "127.0.0.1") -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def free_udp_ports(count: int, host: str = "127.0.0.1", tries: int = 200) -> int:
    """A base port with `count` consecutive free UDP ports (for AutopilotHost)."""
    for _ in range(tries):
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind((host, 0))
            base = int(s.getsockname()[1])
        if base + count > 65535:
            continue
        socks = []
        try:
            for p in range(base, base + count):
                u = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                socks.append(u)
                u.bind((host, p))
            return base
        except OSError:
            continue
        finally:
            for u in socks:
                u.close()
    raise OSError(f"no {count} consecutive free UDP ports")


class EmbeddedBroker:
    """amqtt broker in this process's event loop: `async with EmbeddedBroker() as b: b.url`."""

    def __init__(self, host: str = "127.0.0.1", port: int = 0, plugins: dict | None = None) -> None:
        self.host = host
        self.port = port or free_port(host)
        self.plugins = plugins or {"amqtt.plugins.authentication.AnonymousAuthPlugin": {"allow_anonymous": True}}
        self._broker = None

    @property
    def url(self) -> str:
        return f"mqtt://{self.host}:{self.port}"

    async def start(self) -> None:
        from amqtt.broker import Broker  # imported late: amqtt is slow to import

        for name in ("amqtt", "transitions"):
            logging.getLogger(name).setLevel(logging.WARNING)
        self._broker = Broker(
            {
                "listeners": {"default": {"type": "tcp", "bind": f"{self.host}:{self.port}", "max_connections": 0}},
                "plugins": self.plugins,
            }
        )
        await self._broker.start()

    async def stop(self) -> None:
        if self._broker is not None:
            with contextlib.suppress(Exception):  # amqtt can raise on shutdown of a half-dead session
                async with asyncio.timeout(5):
                    await self._broker.shutdown()
            self._broker = None

    async def __aenter__(self) -> EmbeddedBroker:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.stop()


WORKDIR_PREFIX = "plmarl-broker-"


def remove_stale_workdirs(tmp: str | None = None) -> list[Path]:
    """Delete broker scratch folders (password hashes, ACLs) whose owning process is gone:
    `WORKDIR_PREFIX<kind>-<pid>-*` in the temp directory. Returns what it removed."""
    removed = []
    for d in Path(tmp or tempfile.gettempdir()).glob(f"{WORKDIR_PREFIX}*-*-*"):
        try:
            pid = int(d.name[len(WORKDIR_PREFIX):].split("-")[1])
            os.kill(pid, 0)
            continue  # the owner lives (or is another user's: PermissionError below)
        except ProcessLookupError:
            pass
        except (ValueError, IndexError, PermissionError):
            continue
        shutil.rmtree(d, ignore_errors=True)
        removed.append(d)
    return removed


class _BrokerChild:
    """A broker in a child process on a free loopback port; subclasses say which command."""

    what = "broker"

    def __init__(self, host: str = "127.0.0.1", port: int = 0, access: BrokerAccess | None = None) -> None:
        self.host = host
        self.port = port or free_port(host)
        self.access = access  # None: anonymous clients may do anything
        self.proc: subprocess.Popen[bytes] | None = None
        self._dir: tempfile.TemporaryDirectory[str] | None = None

    @property
    def url(self) -> str:
        return f"mqtt://{self.host}:{self.port}"

    def command(self, workdir: Path) -> list[str]:
        """The child's command line; `workdir` is a scratch directory for config files."""
        raise NotImplementedError

    def start(self, timeout_s: float = 5.0, scratch_in: Path | None = None) -> None:
        """Start the child and wait until it listens. Its config files go to a 0700 folder
        inside `scratch_in` (a launcher's run folder: nothing is left in /tmp even if the
        launcher is SIGKILLed), or to the temp directory."""
        remove_stale_workdirs()
        # 0700: the password files stay ours. The prefix names this process: a SIGKILLed
        # owner cannot clean up, and the next broker started on the machine does it for it.
        self._dir = tempfile.TemporaryDirectory(prefix=f"{WORKDIR_PREFIX}{self.what}-{os.getpid()}-", dir=scratch_in)
        workdir = Path(self._dir.name)
        # stderr to a file, not a pipe: nobody reads a pipe once the broker runs, and a
        # chatty broker (amqtt logs every dropped client) would block on a full one.
        err_path = workdir / "stderr.log"
        with open(err_path, "wb") as err:
            # Never outlive the launcher or test that started us, even a SIGKILLed one.
            self.proc = subprocess.Popen(self.command(workdir), stdout=subprocess.DEVNULL, stderr=err,
                                         preexec_fn=die_with_parent)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                tail = err_path.read_text(errors="replace").strip()[-500:]
                code = self.proc.returncode
                self.stop()
                raise RuntimeError(f"{self.what} exited with {code}: {tail}")
            with contextlib.suppress(OSError), socket.create_connection((self.host, self.port), timeout=0.2):
                return
            time.sleep(0.05)
        self.stop()
        raise TimeoutError(f"{self.what} did not listen on {self.port} within {timeout_s} s")

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(3)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(3)
        self.proc = None
        if self._dir is not None:
            self._dir.cleanup()
            self._dir = None

    def __enter__(self) -> _BrokerChild:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


class MosquittoBroker(_BrokerChild):
    """A mosquitto child process on a free port, localhost only: anonymous, or with the
    logins and ACL of a `BrokerAccess`."""

    what = "mosquitto"

    def __init__(self, host: str = "127.0.0.1", port: int = 0, binary: str = MOSQUITTO, access: BrokerAccess | None = None) -> None:
        super().__init__(host, port, access)
        self.binary = binary

    def command(self, workdir: Path) -> list[str]:
        conf = workdir / "mosquitto.conf"
        if self.access is None:
            auth = "allow_anonymous true\n"
        else:
            passwd, acl = self.access.write_mosquitto(workdir)
            auth = f"allow_anonymous false\npassword_file {passwd}\nacl_file {acl}\nuse_username_as_clientid true\n"
        # As root, mosquitto would drop to the `mosquitto` user, which cannot read our 0600
        # files, and a change of credentials clears its parent-death signal (die_with_parent):
        # a SIGKILLed launcher would leave it running. It stays the launcher's own user.
        conf.write_text(f"listener {self.port} {self.host}\n{auth}user {getpass.getuser()}\n"
                        "persistence false\nlog_dest stderr\nlog_type error\n"
                        # Nagle's algorithm on the broker's side holds small deliveries for the
                        # subscriber's delayed ACK (40 ms): a signalling hop must not wait.
                        "set_tcp_nodelay true\n")
        return [self.binary, "-c", str(conf)]


class AmqttProcess(_BrokerChild):
    """The embedded amqtt broker in a child process (`bus.amqtt_main`): a swarm launcher's
    default, so that the broker does not compete with the SITL world for one event loop."""

    what = "amqtt"

    def command(self, workdir: Path) -> list[str]:
        cmd = [sys.executable, "-m", "plmarl_sitl.sitl.network.amqtt_child", "--host", self.host, "--port", str(self.port)]
        if self.access is not None:
            plugins = workdir / "plugins.json"
            plugins.write_text(json.dumps(self.access.write_amqtt(workdir)))
            cmd += ["--plugins", str(plugins)]
        return cmd


@contextlib.asynccontextmanager
async def local_broker(kind: str = "auto") -> AsyncIterator[EmbeddedBroker | MosquittoBroker]:
    """A broker on a free loopback port for the block: "mosquitto", "amqtt" (in-process),
    or "auto" (mosquitto when installed, the closer match to a deployment; else amqtt)."""
    if kind == "auto":
        kind = "mosquitto" if Path(MOSQUITTO).exists() else "amqtt"
    if kind == "mosquitto":
        mosq = MosquittoBroker()
        mosq.start()
        try:
            yield mosq
        finally:
            mosq.stop()
    elif kind == "amqtt":
        async with EmbeddedBroker() as emb:
            yield emb
    else:
        raise ValueError(f"unknown broker kind {kind!r}")
