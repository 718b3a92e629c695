"""Broker access control for a SITL swarm: one login per process and what each may publish and read.

`BrokerAccess(swarm, n)` makes a random password for every principal of a run:

    agentI   publishes tx/I;            reads rx/I, closed, tick, sense/I, demand, start, ctl
    world    publishes rx/+, closed, tick, sense/+, demand, start, ctl, metrics;  reads tx/+
    monitor  reads tx/+, rx/+, metrics (the launcher's own observer)
    view     reads tx/+, rx/+, metrics (`plmarl swarm status`)

and writes, for the broker we start, mosquitto's `password_file` (PBKDF2-SHA512 hashes by
`mosquitto_passwd -U`) and `acl_file` (one `user` block per principal), or the plugin
configuration of the embedded amqtt broker (its stock `FileAuthPlugin` with argon2 hashes
and `TopicAccessControlListPlugin` with publish and subscribe lists), and for every
client a credentials file (`deploy/mqtt/credentials.py`, mode 0600).
"""

from __future__ import annotations

import secrets
import shutil
import subprocess
from dataclasses import dataclass
from pathlib import Path

from plmarl_sitl.deploy.mqtt.auth import write_private
from plmarl_sitl.deploy.mqtt.credentials import write_credentials
from plmarl_sitl.deploy.mqtt.schema import Topics

MOSQUITTO_PASSWD = shutil.which("mosquitto_passwd") or "/usr/bin/mosquitto_passwd"


@dataclass(frozen=True)
class Principal:
    username: str
    password: str
    publish: tuple[str, ...]
    read: tuple[str, ...]

    @property
    def credentials(self) -> tuple[str, str]:
        return self.username, self.password


class BrokerAccess:
    def __init__(self, swarm: str, n: int) -> None:
        t = Topics(swarm)
        self.swarm = swarm

        def login(name: str, publish: list[str], read: list[str]) -> Principal:
            return Principal(name, secrets.token_hex(16), tuple(publish), tuple(read))

        observer = [t.tx("+"), t.rx("+"), t.metrics]
        self.principals: dict[str, Principal] = {
            "world": login("world", [t.rx("+"), t.closed, t.tick, t.sense("+"), t.demand, t.start, t.ctl, t.metrics], [t.tx("+")]),
            "monitor": login("monitor", [], observer),
            "view": login("view", [], observer),
        }
        for i in range(n):
            self.principals[f"agent{i}"] = login(f"agent{i}", [t.tx(i)], [t.rx(i), t.closed, t.tick, t.sense(i), t.demand, t.start, t.ctl])

    def add(self, name: str, publish: list[str], read: list[str]) -> Principal:
        """One more login (an operator's tool, or a test's intruder)."""
        self.principals[name] = Principal(name, secrets.token_hex(16), tuple(publish), tuple(read))
        return self.principals[name]

    def agent(self, i: int) -> Principal:
        return self.principals[f"agent{i}"]

    def __getitem__(self, name: str) -> Principal:
        return self.principals[name]

    def write_credentials(self, directory: Path) -> dict[str, Path]:
        """One credentials file per principal, `directory/NAME.cred` (0600; directory 0700)."""
        directory.mkdir(mode=0o700, parents=True, exist_ok=True)
        paths = {}
        for name, p in self.principals.items():
            paths[name] = directory / f"{name}.cred"
            write_credentials(paths[name], p.username, p.password)
        return paths

    # ------------------------------------------------------------------ mosquitto
    def acl_text(self) -> str:
        blocks = []
        for p in self.principals.values():
            lines = [f"user {p.username}"] + [f"topic write {x}" for x in p.publish] + [f"topic read {x}" for x in p.read]
            blocks.append("\n".join(lines))
        return "\n\n".join(blocks) + "\n"

    def write_mosquitto(self, workdir: Path) -> tuple[Path, Path]:
        """mosquitto's password file (hashed by mosquitto_passwd) and ACL file in `workdir`."""
        passwd, acl = workdir / "passwd", workdir / "acl"
        write_private(passwd, "".join(f"{p.username}:{p.password}\n" for p in self.principals.values()))
        subprocess.run([MOSQUITTO_PASSWD, "-U", str(passwd)], check=True, capture_output=True)
        write_private(acl, self.acl_text())
        return passwd, acl

    # ------------------------------------------------------------------ amqtt
    def write_amqtt(self, workdir: Path) -> dict:
        """The amqtt broker's `plugins` configuration, its password file in `workdir`."""
        from pwdlib import PasswordHash
        from pwdlib.hashers.argon2 import Argon2Hasher

        # Cheap argon2 parameters on purpose: amqtt verifies in its event loop, and at the
        # defaults (64 MiB, t = 3: 0.3 s a login here) the 22 logins of a 20-UAV swarm blocked
        # the broker past every client's connect timeout, for ever. The passwords are 128-bit
        # random tokens, so a slow hash adds nothing (it protects guessable passwords).
        hasher = PasswordHash((Argon2Hasher(time_cost=1, memory_cost=1024, parallelism=1),))
        passwd = workdir / "amqtt.passwd"
        write_private(passwd, "".join(f"{p.username}:{hasher.hash(p.password)}\n" for p in self.principals.values()))
        return {
            "amqtt.plugins.authentication.FileAuthPlugin": {"password_file": str(passwd)},
            "amqtt.plugins.topic_checking.TopicAccessControlListPlugin": {
                "publish_acl": {p.username: list(p.publish) for p in self.principals.values()},
                "acl": {p.username: list(p.read) for p in self.principals.values()},  # what each may subscribe to
            },
        }
