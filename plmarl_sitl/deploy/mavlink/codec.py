"""MAVLink 2 codec: with its fast path (`pymavlink_fastpath`), the only place that imports pymavlink.

Why a wrapper: UDP carries whole frames per datagram, but pymavlink's parser is a byte
stream parser that keeps a partial frame waiting for more bytes. Over UDP a partial frame
is a *truncated* datagram, and leaving it in the buffer would corrupt the next datagram.
`Codec.decode_datagram` therefore parses one datagram at a time, resets the parser after
it, and classifies every fault (garbage, truncated, bad CRC, bad signature, ...) so the
emulator can count bad input per vehicle instead of crashing or silently desyncing.

Callers build messages with `codec.mav.<name>_encode(...)` (the pymavlink dialect
object) and use constants from `dialect`, so no other module needs to import pymavlink.
Datagrams of whole, well-formed frames are parsed, and frames of fixed-layout messages
(all telemetry, commands and setpoints) packed, by `pymavlink_fastpath`: byte for byte
what pymavlink does, at a fraction of its CPU; any other datagram goes to pymavlink's
parser, which classifies its faults as before.
"""

from __future__ import annotations

import struct
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import ardupilotmega as dialect

from plmarl_sitl.deploy.mavlink import pymavlink_fastpath as fastpath

__all__ = ["Codec", "Decoded", "FAULTS", "Fields", "dialect", "Message", "encode_param_value", "decode_param_value"]

Message = dialect.MAVLink_message

#: Fault categories a datagram can be dropped for, in the order they are reported.
FAULTS = (
    "garbage",  # bytes that are not the start of a MAVLink frame
    "truncated",  # the datagram ends inside a frame
    "bad_header",  # impossible length / incompat flags
    "bad_crc",
    "unknown_msg",  # message id this dialect does not know (cannot check its CRC)
    "unsigned",  # signing is on and the frame is unsigned (and not on the allow list)
    "bad_signature",  # signing is on and the signature or timestamp is wrong
    "bad_value",  # decodes, but a used field is NaN/inf/out of range or unsupported
)

# Seconds between the Unix epoch and the MAVLink signing epoch (2015-01-01 00:00:00 UTC).
_SIGNING_EPOCH = 1420070400
# A new signing stream is accepted only if its timestamp is at most this far behind ours
# (10 us ticks: 60 s, MAVLINK_SIGNING_TIMESTAMP_LIMIT of the C library and pymavlink).
_NEW_STREAM_LIMIT = 60 * 100_000
MAX_SIGNING_STREAMS = 16  # MAVLINK_MAX_SIGNING_STREAMS: (sysid, compid, link id) triples remembered


def signing_timestamp(unix_s: float | None = None) -> int:
    """A MAVLink 2 signing timestamp: 10 us ticks since 2015-01-01 (now, or at `unix_s`)."""
    return int(((time.time() if unix_s is None else unix_s) - _SIGNING_EPOCH) * 100_000)


class _MAVLink(dialect.MAVLink):
    """pymavlink's MAVLink with the signature check in the order of the C library (the
    one ArduPilot and PX4 run): the signature first, then the stream's timestamp.

    pymavlink records a stream's timestamp *before* it checks the signature, so one
    forged frame with a timestamp near 2^48 and a genuine sender's (sysid, compid, link
    id) would make every later genuine frame of that sender an "old timestamp": anyone
    could cut the agent off its vehicle without the key. Here a frame that does not
    verify changes nothing."""

    def check_signature(self, msgbuf: bytearray, srcSystem: int, srcComponent: int) -> bool:
        s = self.signing
        assert s.secret_key is not None
        if fastpath.signature(s.secret_key, msgbuf[:-6]) != msgbuf[-6:]:
            return False
        link_id = msgbuf[-13]
        timestamp = int.from_bytes(msgbuf[-12:-6], "little")
        stream = (link_id, srcSystem, srcComponent)
        last = s.stream_timestamps.get(stream)
        if last is None:
            if len(s.stream_timestamps) >= MAX_SIGNING_STREAMS or timestamp + _NEW_STREAM_LIMIT < s.timestamp:
                return False
        elif timestamp <= last:
            return False  # a replay, or a reordered frame
        s.stream_timestamps[stream] = timestamp
        s.timestamp = max(s.timestamp, timestamp)  # our next timestamp is at least the newest seen
        return True


class Fields(tuple):
    """A message to send as (its id, its fields in declaration order): `Codec.encode` packs
    it as it packs the message object `dialect.mavlink_map[msgid](*fields)`. A plain tuple
    underneath (built in C, no Python call: one is made per telemetry sample)."""

    __slots__ = ()

    @property
    def msgid(self) -> int:
        return self[0]

    @property
    def fields(self) -> tuple:
        return self[1]

    def message(self) -> Message:
        """The message object it stands for (to read its fields by name)."""
        return dialect.mavlink_map[self[0]](*self[1])


@dataclass
class Decoded:
    """The good messages of one datagram and the first fault found in it (if any)."""

    messages: list[Message] = field(default_factory=list)
    fault: str | None = None


def _classify(bad: dialect.MAVLink_bad_data) -> str:
    reason = bad.reason
    if reason.startswith("Bad prefix"):
        return "garbage"
    if "CRC" in reason:
        return "bad_crc"
    if "signature" in reason.lower():
        data = bad.data
        signed = len(data) > 2 and data[0] == dialect.PROTOCOL_MARKER_V2 and data[2] & dialect.MAVLINK_IFLAG_SIGNED
        return "bad_signature" if signed else "unsigned"
    return "bad_header"


class Codec:
    """Encoder and per-datagram decoder for one MAVLink endpoint (sysid, compid).

    With `signing_key`, outgoing frames are signed and incoming frames must carry a good
    signature with a fresh timestamp (a stream's timestamps only go up; a new stream may
    be at most 60 s behind), except the message ids in `allow_unsigned` (ArduPilot: radio
    status reports). A frame signed under another key, or replayed, is `bad_signature`;
    one without a signature `unsigned`. Outgoing timestamps follow the wall clock (and
    never fall behind what a peer sent), as the MAVLink signing spec asks.
    """

    def __init__(
        self,
        sysid: int,
        compid: int,
        signing_key: bytes | None = None,
        allow_unsigned: Iterable[int] = (),
        link_id: int = 0,
    ) -> None:
        self.mav = _MAVLink(None, sysid, compid)
        self.mav.robust_parsing = True
        self._allow_unsigned = frozenset(allow_unsigned)
        if signing_key is not None:
            self.set_signing_key(signing_key, link_id)

    @property
    def sysid(self) -> int:
        return self.mav.srcSystem

    @sysid.setter
    def sysid(self, value: int) -> None:
        self.mav.srcSystem = value

    @property
    def signing(self) -> bool:
        return self.mav.signing.secret_key is not None

    def set_signing_key(self, key: bytes, link_id: int = 0) -> None:
        if len(key) != 32:
            raise ValueError("a MAVLink 2 signing key is 32 bytes")
        s = self.mav.signing
        s.secret_key = bytes(key)
        s.sign_outgoing = True
        s.link_id = link_id
        s.timestamp = max(s.timestamp, signing_timestamp())
        s.stream_timestamps.clear()
        allow = self._allow_unsigned
        s.allow_unsigned_callback = lambda _mav, msgid: msgid in allow

    def clear_signing_key(self) -> None:
        """Stop signing and accept unsigned frames again."""
        s = self.mav.signing
        s.secret_key = None
        s.sign_outgoing = False
        s.allow_unsigned_callback = None
        s.stream_timestamps.clear()

    def encode(self, msg: Message | Fields) -> bytes:
        """Pack `msg` with this endpoint's ids, sequence number and (optional) signature."""
        if msg.__class__ is Fields:
            return self.encode_fields(*msg)  # type: ignore[misc]
        s = self.mav.signing
        if s.sign_outgoing:
            # pymavlink only adds 1 per frame; a timestamp that lagged the clock by more
            # than 60 s would be refused by every peer that opens a new stream with us.
            s.timestamp = max(s.timestamp, signing_timestamp())
        buf = fastpath.pack(self.mav, msg)  # type: ignore[arg-type]
        if buf is None:
            buf = msg.pack(self.mav)  # type: ignore[union-attr]
        self.mav.seq = (self.mav.seq + 1) & 0xFF
        return buf

    def encode_fields(self, msgid: int, fields: tuple) -> bytes:
        """`encode(<its class>(*fields))`, the same bytes, without the message object: for
        the frames sent once per telemetry sample (fields in declaration order, as
        `mav.<name>_encode` takes them)."""
        mav = self.mav
        s = mav.signing
        if s.sign_outgoing:
            s.timestamp = max(s.timestamp, signing_timestamp())
        buf = fastpath.pack_fields(mav, msgid, fields)
        if buf is None:
            buf = dialect.mavlink_map[msgid](*fields).pack(mav)
        mav.seq = (mav.seq + 1) & 0xFF
        return buf

    def decode_datagram(self, data: bytes) -> Decoded:
        """Parse exactly one datagram; never raises on bad input."""
        found = fastpath.frames(data) if fastpath.AVAILABLE else None
        if found is not None:
            messages, fault = fastpath.decode(self.mav, data, found)
            return Decoded(messages, fault)
        out = Decoded()
        mav = self.mav
        try:
            msgs = mav.parse_buffer(data) or []
        except Exception:  # noqa: BLE001 - pymavlink can raise odd errors on hostile input
            msgs = []
            out.fault = "bad_header"
        for m in msgs:
            mid = m.get_msgId()
            if mid == dialect.MAVLINK_MSG_ID_BAD_DATA:
                out.fault = out.fault or _classify(m)
            elif mid == dialect.MAVLINK_MSG_ID_UNKNOWN:
                out.fault = out.fault or "unknown_msg"
            else:
                out.messages.append(m)
        if mav.buf_len() > 0:
            out.fault = out.fault or "truncated"
        # Frames never span datagrams: drop whatever is left so the next one starts clean.
        mav.buf = bytearray()
        mav.buf_index = 0
        mav.expected_length = dialect.HEADER_LEN_V1 + 2
        mav.have_prefix_error = False
        return out


# ----------------------------------------------------------------------------------------
# Parameter value encodings
# ----------------------------------------------------------------------------------------

_INT_TYPES = {
    dialect.MAV_PARAM_TYPE_UINT8: "<B",
    dialect.MAV_PARAM_TYPE_INT8: "<b",
    dialect.MAV_PARAM_TYPE_UINT16: "<H",
    dialect.MAV_PARAM_TYPE_INT16: "<h",
    dialect.MAV_PARAM_TYPE_UINT32: "<I",
    dialect.MAV_PARAM_TYPE_INT32: "<i",
}


def encode_param_value(value: float, param_type: int, bytewise: bool) -> float:
    """The float that goes into PARAM_VALUE/PARAM_SET.param_value.

    PX4 packs integers bytewise into the float's bits (MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE);
    ArduPilot casts them C-style. Getting this wrong makes MAVSDK/QGC show garbage.
    """
    fmt = _INT_TYPES.get(param_type)
    if fmt is None or not bytewise:
        return float(value)
    raw = struct.pack(fmt, int(value)).ljust(4, b"\0")
    return struct.unpack("<f", raw)[0]


def decode_param_value(wire: float, param_type: int, bytewise: bool) -> float:
    """Inverse of `encode_param_value`; NaN stays NaN so callers can reject it."""
    fmt = _INT_TYPES.get(param_type)
    if fmt is None or not bytewise:
        return float(wire)
    raw = struct.pack("<f", wire)[: struct.calcsize(fmt)]
    return float(struct.unpack(fmt, raw)[0])


def param_id_str(param_id: str | bytes) -> str:
    """PARAM_* ids arrive as str or bytes depending on the pymavlink version."""
    if isinstance(param_id, bytes):
        param_id = param_id.decode("ascii", "replace")
    return param_id.split("\0", 1)[0]


def enum_name(enum: str, value: int) -> str:
    """Name of a MAVLink enum entry, e.g. enum_name('MAV_RESULT', 4) == 'MAV_RESULT_FAILED'."""
    entry = dialect.enums.get(enum, {}).get(value)
    return entry.name if entry is not None else str(value)


SendFn = Callable[[Message], None]
