"""MAVLink 2 signing keys on disk: one per vehicle, shared by the vehicle and its agent.

A key file is the swarm key's format (`deploy.mqtt.auth`): 32 bytes as 64 hexadecimal
characters, mode 0600. The run directory of `plmarl swarm up` holds `mavlink/vehicleI.key`
(directory 0700), fresh every run; a missing, exposed, unreadable or wrong-size key is a
one-line UserError naming the flag, never a silent fall-back to an unsigned link.
"""

from __future__ import annotations

import os
from pathlib import Path

from plmarl_sitl.deploy.mqtt.auth import create_key_file, load_key


def load_mavlink_key(path: str | Path, flag: str = "--mavlink-key") -> bytes:
    """The 32-byte signing key in `path` (UserError, one line, if it is not a good key file)."""
    return load_key(path, flag).key


def key_file(directory: Path, index: int) -> Path:
    return directory / f"vehicle{index}.key"


def create_key_files(directory: Path, n: int) -> list[bytes]:
    """Fresh random keys for vehicles 0..n-1 in `directory` (created 0700)."""
    directory.mkdir(mode=0o700, parents=True, exist_ok=True)
    os.chmod(directory, 0o700)
    return [create_key_file(key_file(directory, i)).key for i in range(n)]


def load_key_files(directory: Path, n: int, flag: str) -> list[bytes]:
    """The keys of vehicles 0..n-1 in `directory` (DIR/vehicleI.key each)."""
    return [load_mavlink_key(key_file(directory, i), flag) for i in range(n)]
