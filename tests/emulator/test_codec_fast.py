"""The codec's fixed-layout fast path (`pymavlink_fastpath`) is pymavlink, byte for byte
and field for field; this fails when a pymavlink upgrade changes what the fast path reads.

Every fixed-layout message type of the dialect is encoded with random field values by
`Codec.encode` and by pymavlink's own `pack` on an identical endpoint (same sequence
number, same signing state), and the frames must be equal; `Codec.decode_datagram` must
give pymavlink's messages back (type, fields, header, signature flag), and classify the
same faults, bundles included.
"""

from __future__ import annotations

import asyncio
import random
import socket
import struct

import pytest

from plmarl_sitl.deploy.mavlink import pymavlink_fastpath as fastpath
from plmarl_sitl.deploy.mavlink.client import VehicleLink
from plmarl_sitl.deploy.mavlink.codec import Codec, Fields, dialect, signing_timestamp

KEY = bytes(range(32))
OTHER_KEY = bytes(range(1, 33))

_INT_RANGES = {
    "uint8_t": (0, 2**8 - 1), "int8_t": (-(2**7), 2**7 - 1), "uint16_t": (0, 2**16 - 1),
    "int16_t": (-(2**15), 2**15 - 1), "uint32_t": (0, 2**32 - 1), "int32_t": (-(2**31), 2**31 - 1),
    "uint64_t": (0, 2**64 - 1), "int64_t": (-(2**63), 2**63 - 1),
}


def _value(rng: random.Random, ftype: str) -> float | int:
    if ftype in ("float", "double"):
        if rng.random() < 0.3:
            return 0.0  # trailing zeros: the trimmed payload
        x = rng.uniform(-1e4, 1e4)
        return struct.unpack("<f", struct.pack("<f", x))[0] if ftype == "float" else x
    lo, hi = _INT_RANGES[ftype]
    return 0 if rng.random() < 0.3 else rng.randint(lo, hi)


def _random_message(rng: random.Random, cls: type) -> dialect.MAVLink_message:
    return cls(*_random_fields(rng, cls))


def _random_fields(rng: random.Random, cls: type) -> tuple:
    fields = []
    for ftype, order in zip(cls.fieldtypes, cls.orders, strict=True):
        n = cls.array_lengths[order]  # array lengths are in wire order, field types in declaration order
        if ftype == "char":
            text = bytes(rng.randint(32, 126) for _ in range(rng.randint(0, max(n, 1))))
            fields.append(text if n else (text[:1] or b"a"))
        elif n:
            fields.append([_value(rng, ftype) for _ in range(n)])
        else:
            fields.append(_value(rng, ftype))
    return tuple(fields)


def _reference(sysid: int, compid: int, key: bytes | None) -> dialect.MAVLink:
    mav = dialect.MAVLink(None, sysid, compid)
    mav.robust_parsing = True
    if key is not None:
        mav.signing.secret_key = key
        mav.signing.sign_outgoing = True
    return mav


@pytest.mark.parametrize("key", [None, KEY])
def test_encode_is_pymavlink_byte_for_byte(key: bytes | None) -> None:
    rng = random.Random(25)
    ours = Codec(7, 1, key)
    ref = _reference(7, 1, key)
    assert fastpath.AVAILABLE
    packed = [layout for _, layout in sorted(fastpath.LAYOUTS.items()) if layout.wire_values is not None]
    assert len(packed) > 100  # every telemetry, command and setpoint message
    for layout in packed:
        for _ in range(3):
            msg = _random_message(rng, layout.cls)
            ref.seq = ours.mav.seq
            if key is not None:  # ahead of the wall clock, so `encode` does not move it
                ours.mav.signing.timestamp = ref.signing.timestamp = signing_timestamp() + 10**9
            frame = ours.encode(msg)
            assert frame == msg.pack(ref), layout.cls.msgname


@pytest.mark.parametrize("key", [None, KEY])
def test_encode_fields_is_pymavlink_byte_for_byte(key: bytes | None) -> None:
    """The per-sample frames (an agent's setpoint, the world's telemetry) are packed from
    their fields without a message object (`Codec.encode_fields`, `Fields`): the same
    frames pymavlink packs, for every message type of the dialect (those of arrays and
    strings through pymavlink's own pack)."""
    rng = random.Random(27)
    ours = Codec(7, 1, key)
    ref = _reference(7, 1, key)
    for msgid, cls in sorted(dialect.mavlink_map.items()):
        for k in range(2):
            fields = _random_fields(rng, cls)
            msg = cls(*fields)
            ref.seq = ours.mav.seq
            if key is not None:  # ahead of the wall clock, so `encode` does not move it
                ours.mav.signing.timestamp = ref.signing.timestamp = signing_timestamp() + 10**9
            frame = ours.encode_fields(msgid, fields) if k == 0 else ours.encode(Fields((msgid, fields)))
            assert frame == msg.pack(ref), cls.msgname


def test_telemetry_fields_and_setpoint_frames_are_pymavlink() -> None:
    """What the emulator streams every substep (`telemetry.BUILDERS` giving `Fields`) and
    the agent's setpoint (`VehicleLink.send_accel_ned`) are the frames pymavlink packs."""
    from plmarl_sitl.sitl.autopilot import telemetry
    from plmarl_sitl.sitl.autopilot.host import AutopilotHost

    host = AutopilotHost(1, signing_key=KEY)
    v = host.vehicle(0)
    host.advance(1.0)
    built = [b(v) for b in telemetry.BUILDERS.values()]
    fields = [f for f in built if isinstance(f, Fields)]
    assert {f.msgid for f in fields} >= {dialect.MAVLINK_MSG_ID_LOCAL_POSITION_NED, dialect.MAVLINK_MSG_ID_ATTITUDE}
    ref = _reference(v.sysid, 1, KEY)
    for f in fields:
        ref.seq = v.codec.mav.seq
        v.codec.mav.signing.timestamp = ref.signing.timestamp = signing_timestamp() + 10**9
        assert v.codec.encode(f) == f.message().pack(ref), f.message().get_type()
    asyncio.run(_setpoint_frames())


async def _setpoint_frames() -> None:
    """An agent's link to a UDP socket that answers its hello with one signed heartbeat;
    its acceleration setpoints as they arrive there."""
    loop = asyncio.get_running_loop()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as autopilot:
        autopilot.bind(("127.0.0.1", 0))
        autopilot.setblocking(False)
        link = VehicleLink("127.0.0.1", autopilot.getsockname()[1], signing_key=KEY)
        opening = asyncio.ensure_future(link.open(timeout=5.0))
        _, agent = await loop.sock_recvfrom(autopilot, 512)
        hb = _reference(3, 1, KEY)
        hb.signing.timestamp = signing_timestamp()
        await loop.sock_sendto(autopilot, hb.heartbeat_encode(2, 12, 0, 0, 4).pack(hb), agent)
        await opening
        ref = _reference(255, dialect.MAV_COMP_ID_MISSIONPLANNER, KEY)
        for ms, acc in ((0, (0.0, 0.0, 0.0)), (12300, (1.25, -0.5, 3e-3)), (4_294_967_295, (-0.0, 9.5, -2.0))):
            ref.seq = link.codec.mav.seq
            link.codec.mav.signing.timestamp = ref.signing.timestamp = signing_timestamp() + 10**9
            link.send_accel_ned(*acc, time_boot_ms=ms)
            want = ref.set_position_target_local_ned_encode(ms, 3, 1, dialect.MAV_FRAME_LOCAL_NED, 0x0C3F, 0.0, 0.0,
                                                            0.0, 0.0, 0.0, 0.0, *acc, 0.0, 0.0).pack(ref)
            while True:  # hellos may be in between
                data = await loop.sock_recv(autopilot, 512)
                if data[7] == dialect.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED:
                    break
            assert data == want
        link.close()


@pytest.mark.parametrize("key", [None, KEY])
def test_decode_is_pymavlink_field_for_field(key: bytes | None) -> None:
    rng = random.Random(26)
    sender = Codec(9, 1, key)
    receiver = Codec(255, 190, key)
    assert len(fastpath.LAYOUTS) == len(dialect.mavlink_map)  # arrays and strings are parsed too
    for layout in fastpath.LAYOUTS.values():
        bundle = [_random_message(rng, layout.cls) for _ in range(2)]
        data = b"".join(sender.encode(m) for m in bundle)
        assert fastpath.frames(data) is not None  # the fast path takes it
        out = receiver.decode_datagram(data)
        ref = _reference(255, 190, key)
        if key is not None:
            ref.signing.timestamp = receiver.mav.signing.timestamp
        want = ref.parse_buffer(bytearray(data))
        assert out.fault is None
        assert [m.get_type() for m in out.messages] == [m.get_type() for m in want]
        for got, exp in zip(out.messages, want, strict=True):
            assert got.to_dict() == exp.to_dict()
            assert (got.get_srcSystem(), got.get_srcComponent(), got.get_seq(), got.get_crc(), got.get_signed()) == (
                exp.get_srcSystem(), exp.get_srcComponent(), exp.get_seq(), exp.get_crc(), exp.get_signed())
            assert bytes(got.get_msgbuf()) == bytes(exp.get_msgbuf())
            assert vars(got.get_header()) == vars(exp.get_header())


def _lpn(codec: Codec, ms: int = 1000) -> bytes:
    return codec.encode(codec.mav.local_position_ned_encode(ms, 1.0, 2.0, -3.0, 0.5, 0.0, 0.0))


def test_signature_faults_as_before() -> None:
    receiver = Codec(255, 190, KEY)
    good = _lpn(Codec(1, 1, KEY))
    assert receiver.decode_datagram(good).messages
    assert receiver.decode_datagram(good).fault == "bad_signature"  # a replay
    assert Codec(255, 190, KEY).decode_datagram(_lpn(Codec(1, 1, OTHER_KEY))).fault == "bad_signature"
    assert Codec(255, 190, KEY).decode_datagram(_lpn(Codec(1, 1, None))).fault == "unsigned"
    # A signed and an unsigned frame in one datagram: the good one is kept, the other counted.
    mixed = Codec(255, 190, KEY).decode_datagram(_lpn(Codec(1, 1, KEY)) + _lpn(Codec(1, 1, None)))
    assert mixed.fault == "unsigned" and len(mixed.messages) == 1
    # The allow list (RADIO_STATUS on ArduPilot) passes unsigned.
    allow = Codec(255, 190, KEY, allow_unsigned=[dialect.MAVLINK_MSG_ID_RADIO_STATUS])
    plain = Codec(1, 1, None)
    out = allow.decode_datagram(plain.encode(plain.mav.radio_status_encode(1, 2, 3, 4, 5, 6, 7)))
    assert out.fault is None and out.messages[0].get_type() == "RADIO_STATUS"


@pytest.mark.parametrize("cut", ["truncated", "bad_crc", "garbage", "trailing"])
def test_broken_datagrams_go_to_pymavlink(cut: str) -> None:
    good = _lpn(Codec(1, 1, None))
    data = {
        "truncated": good[:-3],
        "bad_crc": good[:-2] + bytes([good[-2] ^ 0xFF, good[-1]]),
        "garbage": b"\x00\x01" + good,
        "trailing": good + good[:5],
    }[cut]
    assert fastpath.frames(data) is None
    out = Codec(255, 190, None).decode_datagram(data)
    assert out.fault == {"truncated": "truncated", "bad_crc": "bad_crc", "garbage": "garbage", "trailing": "truncated"}[cut]
