"""Message authentication of signalling schema version 2: the swarm key and the 9-byte trailer.

One job: prove that a message was made by a holder of the swarm key. A signed message is
the message itself followed by a trailer

    key_id u8 | tag 8 bytes = HMAC-SHA256(key, b"plmarl/2/" + domain + b"\\0" + message)[:8]

(truncated as MAVLink 2 signing truncates its SHA-256 signature). `domain` names the
message class (b"S" state, b"U" sense, b"D" demand, b"start", b"ctl", b"closed"), so a tag
made for one class never verifies as another. `key_id` is the first byte of
SHA-256(b"plmarl key id" + key): it tells a receiver holding another key ("wrong_key",
a provisioning mistake) from a forger ("forged"), and lets a swarm hold two keys while
one is rotated in. Freshness (counters, time window) is the receiver's business: the
tag covers the sender's session, sequence number and instant, which it checks.

A key file is 64 hexadecimal characters (32 bytes) and one optional newline, readable by
its owner only (mode 0600 or stricter); `load_key` refuses anything else, so a missing,
malformed or exposed key is one error at start, never a silent downgrade. `create_key_file`
writes a fresh random one that way.
"""

from __future__ import annotations

import hashlib
import hmac
import os
import secrets
import stat
from dataclasses import dataclass, field
from pathlib import Path

from plmarl_sitl.errors import UserError

KEY_BYTES = 32
TAG_BYTES = 8
TRAILER_BYTES = 1 + TAG_BYTES
_PREFIX = b"plmarl/2/"


class AuthError(Exception):
    """A message that does not authenticate; `reason` is the counter key: `unsigned` (no
    trailer: a version-1 message), `wrong_key` (signed under another key id) or `forged`
    (our key id and a wrong tag, or too short to hold a trailer at all)."""

    def __init__(self, reason: str) -> None:
        self.reason = reason
        super().__init__(reason)


def key_id_of(key: bytes) -> int:
    return hashlib.sha256(b"plmarl key id" + key).digest()[0]


@dataclass(frozen=True)
class SwarmKey:
    key: bytes = field(repr=False)
    key_id: int = field(init=False)

    def __post_init__(self) -> None:
        if len(self.key) != KEY_BYTES:
            raise ValueError(f"a swarm key has {KEY_BYTES} bytes")
        object.__setattr__(self, "key_id", key_id_of(self.key))

    @classmethod
    def generate(cls) -> SwarmKey:
        return cls(secrets.token_bytes(KEY_BYTES))

    def tag(self, domain: bytes, message: bytes) -> bytes:
        return hmac.digest(self.key, _PREFIX + domain + b"\0" + message, "sha256")[:TAG_BYTES]

    def seal(self, domain: bytes, message: bytes) -> bytes:
        """The message with its trailer."""
        return message + bytes((self.key_id,)) + self.tag(domain, message)

    def open(self, domain: bytes, payload: bytes) -> bytes:
        """The message of a sealed payload; AuthError if it does not authenticate."""
        if len(payload) <= TRAILER_BYTES:
            raise AuthError("forged")
        message, kid, tag = payload[:-TRAILER_BYTES], payload[-TRAILER_BYTES], payload[-TAG_BYTES:]
        if kid != self.key_id:
            raise AuthError("wrong_key")
        if not hmac.compare_digest(tag, self.tag(domain, message)):
            raise AuthError("forged")
        return message


def create_key_file(path: Path) -> SwarmKey:
    """A fresh random key written to `path` (replacing any) with mode 0600."""
    key = SwarmKey.generate()
    write_private(path, key.key.hex() + "\n")
    return key


def write_private(path: Path, text: str) -> None:
    """Write a secret file readable by its owner only (created 0600; never widened)."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    os.fchmod(fd, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(text)


def read_private(path: str | Path, flag: str, what: str) -> str:
    """A secret file's text; UserError (one line, naming `flag`) when it cannot be read or
    others than its owner may access it."""
    p = Path(path)
    try:
        st = p.stat()
        text = p.read_text()
    except OSError as exc:
        raise UserError(f"{flag} {path}: cannot read the {what} ({exc.strerror or exc})") from None
    if st.st_mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise UserError(f"{flag} {path}: the {what} is accessible to others (mode {stat.S_IMODE(st.st_mode):o}); "
                        f"chmod 600 it, and make a new one if someone may have read it")
    return text


def load_key(path: str | Path, flag: str = "--swarm-key") -> SwarmKey:
    """The key in a key file; UserError (one line, naming `flag`) when it is missing,
    readable by others than its owner, or not 64 hex characters."""
    text = read_private(path, flag, "key file")
    try:
        key = bytes.fromhex(text.strip())
    except ValueError:
        key = b""
    if len(key) != KEY_BYTES or len(text.strip()) != 2 * KEY_BYTES:
        raise UserError(f"{flag} {path}: not a key file ({2 * KEY_BYTES} hexadecimal characters expected)")
    return SwarmKey(key)


def key_from_flags(path: str | None, no_auth: bool) -> SwarmKey | None:
    """`--swarm-key FILE` / `--no-auth` of a program: the key, None with an explicit
    --no-auth, and a UserError with neither (never a silent downgrade)."""
    if no_auth:
        return None
    if path is None:
        raise UserError("no --swarm-key FILE: the swarm's messages are signed (docs/SECURITY.md); "
                        "give the key file, or --no-auth to run unsigned")
    return load_key(path)
