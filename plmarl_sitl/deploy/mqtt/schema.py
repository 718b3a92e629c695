"""The signalling wire format (schema version 4): compact binary state and sensing messages.

docs/SIGNALLING.md is the contract. All integers little-endian. A state message is the
sparse signalling update of Algorithm 1: kind 'S' (38 bytes, schema 1-2), kind 'G' (74
bytes, schema 3: the same fields, then the sender's knowledge of failures: its plan epoch
and failed-set bitmask) or, since schema version 4, kind 'I' (39 + 7 x count bytes: the
fields of 'S', then the sender's knowledge, model/gossip.py: for each identity declared
failed or above incarnation 0, its incarnation and the instant of its declaration); a
sensing message lists the users a
vehicle's payload sensor sees. Decoders never raise anything but `Malformed`, whose
`reason` feeds the receive counters.

Topics (`Topics(swarm)`): tx/<id> (agent -> link emulator or radio), rx/<id> (what the
link delivered to <id>), sense/<id>, demand (binary, retained; codec in `demand.py`),
metrics (JSON), start (JSON, retained), ctl (JSON).
"""

from __future__ import annotations

import json
import math
import struct
from dataclasses import dataclass, field

from plmarl_sitl.model.knowledge import Known

# The contract's version (docs/SIGNALLING.md). 2 adds the demand message (issue 12) and
# signed messages (issue 14: version byte / "v" 2 and an authentication trailer, `auth.py`,
# `wire.py`); the messages of version 1 are unchanged and keep their version byte, VERSION.
# 3 adds the state message with gossip, kind 'G' (issue 24): a new kind, not a changed one,
# so a receiver of schema 2 counts it as malformed_kind and one of schema 3 still reads 'S'
# (as knowing no failure). 4 adds kind 'I' (issue 24: a declared UAV heard again is taken
# back at a newer incarnation, model/gossip.py): again a new kind, so a receiver of schema 3
# counts it as malformed_kind (a clear, counted drop), and one of schema 4 still reads 'G'
# and 'S' (every incarnation 0; a 'G' names its epoch as every declaration's instant).
# Agents of schema 4 send 'I'.
SCHEMA_VERSION = 4
VERSION = 1
SIGNED_VERSION = 2
KIND_STATE = ord("S")
KIND_GOSSIP_STATE = ord("G")
KIND_INCARNATION_STATE = ord("I")
FAILED_MASK_BYTES = 32  # the failed set: bit j of byte j // 8 = identity j (ids 0..255)
KIND_SENSE = ord("U")
MAX_ABS_POS_M = 1.0e6
MAX_ABS_VEL_MPS = 1.0e3
MAX_SENSED_USERS = 4096

# How long past a signalling instant an agent waits for its updates, in vehicle seconds:
# at most max(INSTANT_WAIT_MIN_S, INSTANT_WAIT_WALL_S x the speedup). The SITL link
# emulator closes an instant whose updates are not all in after half that wall bound.
INSTANT_WAIT_MIN_S = 0.2
INSTANT_WAIT_WALL_S = 0.15

# Signed state messages only: the freshness window around the receiver's own mission time.
# A state older than T_up + this (the next instant's state has superseded it) or newer than
# this (no sender can be ahead of the receiver's clock by more) is `out_of_window`.
WINDOW_SLACK_S = 5.0

# version, kind, sender, session, seq, t_ms, p_n, p_e, p_d, v_n, v_e, v_d
_STATE = struct.Struct("<BBHHIi6f")
# then (kind 'G'): epoch_s (u32), failed mask (32 bytes)
_GOSSIP = struct.Struct(f"<I{FAILED_MASK_BYTES}s")
# then (kind 'I'): count (u8), then count x (identity u8, incarnation u16, declared at s u32:
# 0 = not failed), identities ascending
_COUNT = struct.Struct("<B")
_ENTRY = struct.Struct("<BHI")
MAX_INCARNATION = 0xFFFF
# version, kind, receiver, t_ms, count; then count x (north, east) float32
_SENSE_HEAD = struct.Struct("<BBHiH")
STATE_SIZE = _STATE.size + _COUNT.size  # what a schema-4 agent sends (kind 'I') knowing nothing
STATE_SIZES = {KIND_STATE: _STATE.size, KIND_GOSSIP_STATE: _STATE.size + _GOSSIP.size, KIND_INCARNATION_STATE: STATE_SIZE}


def state_size(payload: bytes, at: int = 0) -> int:
    """The length of the state message starting at byte `at` (0: not a state kind): fixed
    for 'S' and 'G', 39 + 7 x count for 'I' (its fixed part if too short to tell)."""
    kind = payload[at + 1] if at + 1 < len(payload) else -1
    size = STATE_SIZES.get(kind, 0)
    if kind == KIND_INCARNATION_STATE and at + size <= len(payload):
        size += _ENTRY.size * payload[at + size - 1]
    return size


class Malformed(ValueError):
    """A payload that is not a valid v1 message; `reason` is a short counter key."""

    def __init__(self, reason: str) -> None:
        self.reason = reason
        super().__init__(reason)


@dataclass(frozen=True)
class StateMsg:
    sender: int
    session: int  # random per agent process: a restarted agent's seq starts again
    seq: int
    t_ms: int  # mission time of the signalling instant (ms)
    state: tuple[float, float, float, float, float, float]  # mission frame NED [p, v]
    # the sender's knowledge (model/knowledge.py): (identity, incarnation, declared at s or 0),
    # for the identities declared failed or above incarnation 0, ascending
    entries: tuple[tuple[int, int, int], ...] = ()

    @classmethod
    def with_knowledge(cls, sender: int, session: int, seq: int, t_ms: int, state: tuple[float, ...], known: Known) -> StateMsg:
        ids = sorted(set(known.failed) | set(known.inc))
        return cls(sender, session, seq, t_ms, state,  # type: ignore[arg-type]
                   tuple((j, known.inc.get(j, 0), known.failed.get(j, 0)) for j in ids))

    def known(self) -> Known:
        """The sender's knowledge this message carries."""
        return Known({j: s for j, _, s in self.entries if s > 0}, {j: c for j, c, _ in self.entries})

    @property
    def t_s(self) -> float:
        return self.t_ms / 1000.0

    def failed_ids(self) -> list[int]:
        return [j for j, _, s in self.entries if s > 0]


def failed_mask(ids: object) -> int:
    """The bitmask of identities `ids` (an iterable of ints 0..255)."""
    out = 0
    for j in ids:  # type: ignore[attr-defined]
        out |= 1 << int(j)
    return out


def encode_state(m: StateMsg) -> bytes:
    """A kind 'I' state message (schema version 4): the state and the sender's knowledge."""
    head = _STATE.pack(VERSION, KIND_INCARNATION_STATE, m.sender, m.session, m.seq & 0xFFFFFFFF, m.t_ms, *m.state)
    entries = sorted(m.entries)
    return (head + _COUNT.pack(len(entries))
            + b"".join(_ENTRY.pack(j, min(c, MAX_INCARNATION), s & 0xFFFFFFFF) for j, c, s in entries))


def _head(payload: bytes, kind: int, size: int) -> None:
    if len(payload) < 2:
        raise Malformed("short")
    if payload[0] != VERSION:
        raise Malformed("version")
    if payload[1] != kind:
        raise Malformed("kind")
    if len(payload) < size:
        raise Malformed("short")


def decode_state(payload: bytes) -> StateMsg:
    """A state message of kind 'I', or 'G' (schema 3, every incarnation 0), or 'S' (schema
    1-2), which carries no knowledge."""
    kind = payload[1] if len(payload) >= 2 and payload[1] in STATE_SIZES else KIND_STATE
    _head(payload, kind, STATE_SIZES[kind])
    if len(payload) != state_size(payload):
        raise Malformed("length")
    _, _, sender, session, seq, t_ms, *s = _STATE.unpack_from(payload)
    entries: tuple[tuple[int, int, int], ...] = ()
    if kind == KIND_GOSSIP_STATE:  # schema 3: every declaration at its plan epoch, incarnation 0
        epoch_s, mask = _GOSSIP.unpack_from(payload, _STATE.size)
        bits = int.from_bytes(mask, "little")
        entries = tuple((j, 0, max(epoch_s, 1)) for j in range(8 * FAILED_MASK_BYTES) if bits >> j & 1)
    if kind == KIND_INCARNATION_STATE:
        at = STATE_SIZES[kind]
        entries = tuple(_ENTRY.unpack_from(payload, at + _ENTRY.size * i) for i in range(payload[at - 1]))
        if any(c == 0 and since == 0 for _, c, since in entries) or [j for j, _, _ in entries] != sorted({j for j, _, _ in entries}):
            raise Malformed("knowledge")  # empty entries are left out, identities ascend once each
    if not all(math.isfinite(x) for x in s):
        raise Malformed("not_finite")
    if any(abs(x) > MAX_ABS_POS_M for x in s[:3]) or any(abs(x) > MAX_ABS_VEL_MPS for x in s[3:]):
        raise Malformed("out_of_range")
    return StateMsg(sender, session, seq, t_ms, tuple(s), entries)  # type: ignore[arg-type]


def split_states(payload: bytes, trailer: int = 0) -> list[bytes]:
    """The state messages of an rx payload: one, or several back to back (the SITL link
    emulator delivers an instant's updates to a receiver in one message), each as long as
    its kind says (byte 1: 'S', 'G' or 'I', `state_size`; a signed one `trailer` bytes longer). Raises
    Malformed("length") when the payload is not whole messages; each part is then decoded
    (and counted if malformed) on its own."""
    parts, i, n = [], 0, len(payload)
    while i < n:
        size = state_size(payload, i) + trailer
        if i == 0 and (size == trailer or size >= n):
            return [payload]  # one message (or not a state): its decoder says what is wrong
        if size == trailer or i + size > n:
            raise Malformed("length")
        parts.append(payload[i : i + size])
        i += size
    return parts


def peek_sender(payload: bytes) -> int:
    """The sender id of a state message (the link emulator routes without a full decode)."""
    return decode_state(payload).sender


@dataclass(frozen=True)
class SenseMsg:
    receiver: int
    t_ms: int
    users: tuple[tuple[float, float], ...]  # mission-frame (north, east) of the sensed users


def encode_sense(receiver: int, t_ms: int, users_ne: list[tuple[float, float]] | object) -> bytes:
    pts = [(float(n), float(e)) for n, e in users_ne]  # type: ignore[union-attr]
    if len(pts) > MAX_SENSED_USERS:
        pts = pts[:MAX_SENSED_USERS]
    body = struct.pack(f"<{2 * len(pts)}f", *[c for p in pts for c in p])
    return _SENSE_HEAD.pack(VERSION, KIND_SENSE, receiver, t_ms, len(pts)) + body


def decode_sense(payload: bytes) -> SenseMsg:
    _head(payload, KIND_SENSE, _SENSE_HEAD.size)
    _, _, receiver, t_ms, count = _SENSE_HEAD.unpack_from(payload)
    if len(payload) != _SENSE_HEAD.size + 8 * count:
        raise Malformed("length")
    flat = struct.unpack_from(f"<{2 * count}f", payload, _SENSE_HEAD.size)
    # The same test as all(isfinite(x) and abs(x) <= MAX) per value, iterated in C: a
    # generator over ~100 values per message was ~2 % of an agent's CPU (issue 25).
    if not (all(map(math.isfinite, flat)) and (not flat or max(map(abs, flat)) <= MAX_ABS_POS_M)):
        raise Malformed("not_finite")
    return SenseMsg(receiver, t_ms, tuple(zip(flat[0::2], flat[1::2], strict=True)))


def encode_json(obj: dict, version: int = VERSION) -> bytes:
    return json.dumps({"v": version, **obj}, separators=(",", ":")).encode()


def decode_json(payload: bytes, version: int = VERSION) -> dict:
    try:
        obj = json.loads(payload)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise Malformed("json") from exc
    if not isinstance(obj, dict):
        raise Malformed("json")
    if obj.get("v") != version:
        raise Malformed("version")
    return obj


@dataclass(frozen=True)
class Topics:
    swarm: str = "sitl"

    @property
    def root(self) -> str:
        return f"plmarl/{self.swarm}"

    def tx(self, i: int | str) -> str:
        return f"{self.root}/tx/{i}"

    def rx(self, i: int | str) -> str:
        return f"{self.root}/rx/{i}"

    def sense(self, i: int | str) -> str:
        return f"{self.root}/sense/{i}"

    @property
    def demand(self) -> str:
        """The published user-density map (retained)."""
        return f"{self.root}/demand"

    @property
    def metrics(self) -> str:
        return f"{self.root}/metrics"

    @property
    def start(self) -> str:
        return f"{self.root}/start"

    @property
    def ctl(self) -> str:
        return f"{self.root}/ctl"

    @property
    def tick(self) -> str:
        """Lockstep SITL only: the world has published everything of a boot second (retained)."""
        return f"{self.root}/tick"

    @property
    def closed(self) -> str:
        """SITL only: the link emulator has delivered everything of a signalling instant."""
        return f"{self.root}/closed"

    def id_of(self, topic: str) -> int | None:
        """The trailing integer id of a per-vehicle topic (None if not one)."""
        tail = topic.rsplit("/", 1)[-1]
        return int(tail) if tail.isdigit() else None


@dataclass
class RxCounters:
    """What a receiver did with incoming signalling payloads."""

    accepted: int = 0
    duplicate: int = 0
    out_of_order: int = 0
    malformed: int = 0
    self_echo: int = 0
    unknown_sender: int = 0
    # Authentication (signed wire, schema version 2): dropped before anything is read.
    unsigned: int = 0  # a version-1 message without a trailer
    wrong_key: int = 0  # signed under another key id
    forged: int = 0  # our key id, a tag that does not verify
    out_of_window: int = 0  # a signed state too old or too new for the receiver's clock
    misattributed: int = 0  # a sender (receiver) id that disagrees with the topic
    reasons: dict[str, int] = field(default_factory=dict)
    auth_reasons: dict[str, int] = field(default_factory=dict)

    def bad(self, reason: str) -> None:
        self.malformed += 1
        self.reasons[reason] = self.reasons.get(reason, 0) + 1

    def refused(self, reason: str, what: str) -> None:
        """An authentication failure `reason` (a counter above) of a message of class `what`."""
        setattr(self, reason, getattr(self, reason) + 1)
        key = f"{what}_{reason}"
        self.auth_reasons[key] = self.auth_reasons.get(key, 0) + 1

    def as_dict(self) -> dict[str, int]:
        plain = {k: v for k, v in self.__dict__.items() if k not in ("reasons", "auth_reasons")}
        return plain | {f"malformed_{k}": v for k, v in self.reasons.items()} | {f"auth_{k}": v for k, v in self.auth_reasons.items()}


class SeqFilter:
    """Per-sender duplicate / out-of-order filter.

    Within one sender session, a message is accepted only if its seq is larger than the
    last accepted one. A new session (a restarted agent) is accepted when its instant is
    not older than the last accepted one, and replaces the old session.
    """

    def __init__(self) -> None:
        self._last: dict[int, tuple[int, int, int]] = {}  # sender -> (session, seq, t_ms)

    def check(self, m: StateMsg) -> str | None:
        """None to accept, else 'duplicate' or 'out_of_order'."""
        last = self._last.get(m.sender)
        if last is not None:
            session, seq, t_ms = last
            if m.session == session:
                if m.seq == seq:
                    return "duplicate"
                if m.seq < seq or m.t_ms < t_ms:
                    return "out_of_order"
            elif m.t_ms < t_ms:
                return "out_of_order"
        self._last[m.sender] = (m.session, m.seq, m.t_ms)
        return None
