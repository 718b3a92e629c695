"""Every use of pymavlink's private message state, in one place, checked against the
pymavlink it runs on: MAVLink 2 frames parsed, and packed, with one precompiled struct.

Why: every telemetry sample of a SITL swarm is one frame packed by the emulator and parsed
by the agent, and its setpoint the same way back. pymavlink frames byte by byte in Python
(`MAVLink.parse_char`) and builds a header object per frame: at N = 20 that was the
largest single item of the rig's CPU after the agents' start-up (docs/RESULTS.md, issue
25). `decode` parses every message type of the dialect with its precompiled struct, and
`pack` packs those of fixed layout (no arrays, no strings: every telemetry, command and
setpoint message; the others are rare and stay pymavlink's) the same way, with
pymavlink's C CRC (`mcrf4xx`) and the same signature rules, giving byte for byte the
frames pymavlink packs and the message objects it parses.

What this relies on, read in pymavlink 2.4.50's generated dialect (`MAVLink_message`,
`MAVLink_message._pack`, `MAVLink.decode`, `MAVLink_header`):
  - a message class's `unpacker`, `orders`, `lengths`, `fieldtypes`, `ordered_fieldnames`
    and `crc_extra` describe its wire layout, and its constructor takes the fields in
    declaration order (field i is wire field orders[i]; a numeric array a list of its
    `lengths` values, a char array one bytes value without its trailing NULs);
  - a parsed message carries `_header`, `_msgbuf`, `_payload`, `_crc`, `_signed` and
    `_link_id`, which its public getters (`get_srcSystem`, `get_msgbuf`, ...) read; its
    constructor makes a fresh `MAVLink_header(msgid)` (filled in here);
  - a MAVLink 2 payload loses its trailing zero bytes on the wire (at least one kept).
When the version is not one of VERIFIED_VERSIONS or `mcrf4xx` (pymavlink's C extension)
is missing, `AVAILABLE` is False and codec.py uses pymavlink alone, logged once.
tests/emulator/test_codec_fast.py compares both ways for every message type of the dialect,
so a pymavlink upgrade that changes any of this fails there, not as corrupt frames.
"""

from __future__ import annotations

import hashlib
import logging
import struct
from collections.abc import Callable
from importlib.metadata import PackageNotFoundError, version
from operator import attrgetter, itemgetter
from typing import Any, NamedTuple

from pymavlink.dialects.v20 import ardupilotmega as dialect

log = logging.getLogger("plmarl.mavlink")

VERIFIED_VERSIONS = ("2.4.50",)  # pymavlink versions whose internals were read and tested as above


class Layout(NamedTuple):
    """A message type's wire layout: its class, struct and where each field sits."""

    cls: type
    unpacker: struct.Struct
    declared: Callable[[tuple], tuple]  # the fields in declaration order from the wire values (no arrays)
    slots: tuple[tuple[int, int], ...] | None  # with arrays: field i is values[tip : tip + n] (n > 1) or values[tip]
    text: bool  # has char fields (bytes, their trailing NULs stripped as pymavlink does)
    crc_extra: bytes
    wire_values: Callable[[Any], tuple] | None  # field values in wire order; None: pymavlink packs it
    wire_order: Callable[[tuple], tuple] | None  # the same from the fields in declaration order


def _layouts() -> dict[int, Layout]:
    out = {}
    for msgid, cls in dialect.mavlink_map.items():
        lengths = list(cls.lengths)
        arrays = sum(lengths) != len(lengths)
        text = any(t == "char" for t in cls.fieldtypes)
        slots = None
        if arrays:  # as pymavlink's decode: wire field `order` starts at the sum of the lengths before it
            slots = tuple((sum(lengths[:o]), lengths[o]) for o in cls.orders)
        getter = reorder = None
        if not arrays and not text:  # packing arrays and strings stays pymavlink's
            names = list(cls.ordered_fieldnames)
            getter = attrgetter(*names) if len(names) > 1 else (lambda m, _n=names[0]: (getattr(m, _n),))
            # wire value j is field source[j] (field i is wire value orders[i])
            source = [0] * len(cls.orders)
            for i, o in enumerate(cls.orders):
                source[o] = i
            reorder = itemgetter(*source) if len(source) > 1 else (lambda f: (f[0],))
        # field i (declaration order) is wire value orders[i]
        declared = itemgetter(*cls.orders) if len(cls.orders) > 1 else (lambda v, _o=cls.orders[0]: (v[_o],))
        out[msgid] = Layout(cls, cls.unpacker, declared, slots, text, bytes([cls.crc_extra]), getter, reorder)
    return out


def _available() -> bool:
    try:
        ver = version("pymavlink")
    except PackageNotFoundError:
        ver = "unknown"
    if ver not in VERIFIED_VERSIONS or getattr(dialect, "mcrf4xx", None) is None:
        log.info("pymavlink %s (fast path verified on %s, C CRC %s): frames go through pymavlink's own parser",
                 ver, ", ".join(VERIFIED_VERSIONS), "present" if getattr(dialect, "mcrf4xx", None) else "missing")
        return False
    return True


AVAILABLE = _available()
LAYOUTS = _layouts() if AVAILABLE else {}
SIGNED = dialect.MAVLINK_IFLAG_SIGNED
SIGNATURE_LEN = dialect.MAVLINK_SIGNATURE_BLOCK_LEN
_HEADER = struct.Struct("<BBBBBBBHB")
_CRC = struct.Struct("<H")
_SIGN_STAMP = struct.Struct("<BQ")
_crc16 = getattr(dialect, "mcrf4xx", None)  # CRC-16/MCRF4XX in C: (data, initial crc) -> crc


_KEYED: dict[bytes, Any] = {}  # signing key -> SHA-256 state after the key (see `signature`)


def signature(key: bytes, signed: bytes | bytearray) -> bytes:
    """The MAVLink 2 signature of a frame: the first 6 bytes of SHA-256(key + frame up to
    the signature). The hash state after the 32-byte key is kept per key and copied:
    hashlib's constructor looks the algorithm up in OpenSSL on every call, and a frame's
    signature is made or checked for every telemetry sample and setpoint."""
    keyed = _KEYED.get(key)
    if keyed is None:
        if len(_KEYED) >= 64:  # keys are few (one per link); never an unbounded cache
            _KEYED.clear()
        keyed = _KEYED[key] = hashlib.sha256(key)
    h = keyed.copy()
    h.update(signed)
    return h.digest()[:6]


def pack(mav: dialect.MAVLink, msg: dialect.MAVLink_message) -> bytes | None:
    """`msg.pack(mav)` byte for byte for a fixed-layout message (None: not one, use pymavlink).
    Signs with `mav.signing` as pymavlink does (and moves its timestamp on by one)."""
    layout = LAYOUTS.get(msg.get_msgId())
    if layout is None or layout.wire_values is None:
        return None
    return _pack(mav, layout, layout.wire_values(msg))


def pack_fields(mav: dialect.MAVLink, msgid: int, fields: tuple) -> bytes | None:
    """`pack` of the message `cls(*fields)` without building it (fields in declaration
    order, as `<name>_encode` takes them): the per-sample frames (an agent's setpoint, the
    world's telemetry) need no message object. None: not a fixed-layout message."""
    layout = LAYOUTS.get(msgid)
    if layout is None or layout.wire_order is None:
        return None
    return _pack(mav, layout, layout.wire_order(fields))


def _pack(mav: dialect.MAVLink, layout: Layout, wire_values: tuple) -> bytes:
    payload = layout.unpacker.pack(*wire_values)
    trimmed = payload.rstrip(b"\0") or payload[:1]
    s = mav.signing
    sign = s.sign_outgoing
    msgid = layout.cls.id
    buf = _HEADER.pack(253, len(trimmed), SIGNED if sign else 0, 0, mav.seq, mav.srcSystem, mav.srcComponent,
                       msgid & 0xFFFF, msgid >> 16) + trimmed
    buf += _CRC.pack(_crc16(buf[1:] + layout.crc_extra, 0xFFFF))
    if sign:
        buf += _SIGN_STAMP.pack(s.link_id, s.timestamp)[:7]
        buf += signature(s.secret_key, buf)
        s.timestamp += 1
    return buf


def frames(data: bytes) -> list[tuple[int, int, Layout]] | None:
    """(start, end, layout) of each frame if `data` is nothing but whole MAVLink 2 frames of
    known messages with good CRCs; None otherwise (pymavlink's parser takes it and
    classifies whatever is wrong, as before)."""
    out = []
    n = len(data)
    i = 0
    while i < n:
        if n - i < 12 or data[i] != 253:
            return None
        mlen, iflags = data[i + 1], data[i + 2]
        if iflags & ~SIGNED:
            return None
        crc_at = i + 10 + mlen
        end = crc_at + 2 + (SIGNATURE_LEN if iflags else 0)
        if end > n:
            return None
        layout = LAYOUTS.get(data[i + 7] | data[i + 8] << 8 | data[i + 9] << 16)
        if layout is None or _crc16(data[i + 1 : crc_at] + layout.crc_extra, 0xFFFF) != data[crc_at] | data[crc_at + 1] << 8:
            return None
        out.append((i, end, layout))
        i = end
    return out or None


def decode(mav: dialect.MAVLink, data: bytes, found: list[tuple[int, int, Layout]]) -> tuple[list, str | None]:
    """The messages of a datagram `frames` accepted, and the first signature fault: the rules
    of pymavlink's `decode` (with signing on: a signed frame must pass `mav.check_signature`,
    else the allow-unsigned callback must accept its id), then one unpack per frame into
    pymavlink's own message class, with the header and buffer pymavlink would give it."""
    messages = []
    fault = None
    s = mav.signing
    key = s.secret_key
    for start, end, layout in found:
        msgbuf = bytearray(data if end - start == len(data) else data[start:end])
        _, mlen, iflags, cflags, seq, src_sys, src_comp, id_low, id_high = _HEADER.unpack_from(msgbuf)
        msgid = id_low | id_high << 16
        signed = iflags & SIGNED
        sig_ok = False
        if key is not None:
            accept = False
            if signed:
                sig_ok = accept = mav.check_signature(msgbuf, src_sys, src_comp)
            allow = s.allow_unsigned_callback
            if not accept and allow is not None:
                accept = allow(mav, msgid)
            if not accept:
                fault = fault or ("bad_signature" if signed else "unsigned")
                continue
        size = layout.unpacker.size
        payload = data[start + 10 : start + 10 + mlen]
        if mlen < size:
            payload += bytes(size - mlen)  # the trailing zeros MAVLink 2 trimmed
        values = layout.unpacker.unpack_from(payload)
        if layout.slots is None:
            fields = layout.declared(values)
        else:
            fields = [values[tip] if n == 1 else list(values[tip : tip + n]) for tip, n in layout.slots]
        if layout.text:
            fields = [f.rstrip(b"\0") if isinstance(f, bytes) else f for f in fields]
        try:
            m = layout.cls(*fields)
        except Exception:  # noqa: BLE001 - as pymavlink's decode: a frame it cannot build is bad data
            fault = fault or "bad_header"
            continue
        m._signed = sig_ok
        if sig_ok:
            m._link_id = msgbuf[-13]
        m._msgbuf = msgbuf
        m._payload = msgbuf[6 : -(2 + (SIGNATURE_LEN if signed else 0))]  # sic: pymavlink's slice
        m._crc = _CRC.unpack_from(msgbuf, 10 + mlen)[0]
        h = m._header  # the constructor's own MAVLink_header(msgid), filled in (one object fewer)
        h.incompat_flags, h.compat_flags, h.mlen, h.seq, h.srcSystem, h.srcComponent = iflags, cflags, mlen, seq, src_sys, src_comp
        messages.append(m)
    return messages, fault
