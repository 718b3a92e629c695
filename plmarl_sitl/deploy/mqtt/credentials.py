"""Broker credentials files: one line `USERNAME:PASSWORD`, readable by the owner only.

Each agent, the world and the live view get their own (`sitl/network/access.py` writes
them for a SITL run); the broker's ACL then limits what that username may publish and
read. A file, not a flag, so the password never shows in `ps`.
"""

from __future__ import annotations

from pathlib import Path

from plmarl_sitl.deploy.mqtt.auth import read_private, write_private
from plmarl_sitl.errors import UserError


def write_credentials(path: Path, username: str, password: str) -> None:
    write_private(path, f"{username}:{password}\n")


def load_credentials(path: str | Path, flag: str = "--broker-credentials") -> tuple[str, str]:
    line = read_private(path, flag, "credentials file").strip()
    user, sep, password = line.partition(":")
    if not sep or not user or not password or "\n" in line:
        raise UserError(f"{flag} {path}: expected one line USERNAME:PASSWORD")
    return user, password
