"""Property tests of the codec: any bytes are handled, frames never leak across datagrams."""

from __future__ import annotations

import math
import struct

from hypothesis import given, settings
from hypothesis import strategies as st

from plmarl_sitl.deploy.mavlink.codec import FAULTS, Codec, decode_param_value, dialect, encode_param_value

d = dialect
floats = st.floats(allow_nan=True, allow_infinity=True, width=32)


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=600))
def test_any_bytes_decode_without_raising(data: bytes) -> None:
    out = Codec(1, 1).decode_datagram(data)
    assert out.fault is None or out.fault in FAULTS
    assert out.fault is not None or out.messages or not data


@settings(max_examples=200, deadline=None)
@given(st.tuples(floats, floats, floats), st.integers(0, 0xFFF), st.integers(1, 255))
def test_setpoint_round_trip(acc: tuple[float, float, float], mask: int, sysid: int) -> None:
    tx, rx = Codec(255, 190), Codec(sysid, 1)
    buf = tx.encode(tx.mav.set_position_target_local_ned_encode(7, sysid, 1, 1, mask, 0, 0, 0, 0, 0, 0, *acc, 0, 0))
    out = rx.decode_datagram(buf)
    assert out.fault is None and len(out.messages) == 1
    m = out.messages[0]
    assert m.type_mask == mask and m.target_system == sysid
    for a, b in zip((m.afx, m.afy, m.afz), acc, strict=True):
        assert (math.isnan(a) and math.isnan(b)) or a == b


@settings(max_examples=200, deadline=None)
@given(st.integers(1, 60), st.data())
def test_truncated_frame_does_not_poison_the_next_datagram(cut_from_end: int, data: st.DataObject) -> None:
    tx, rx = Codec(255, 190), Codec(1, 1)
    frame = tx.encode(tx.mav.command_long_encode(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0))
    cut = frame[: max(1, len(frame) - cut_from_end)]
    assert rx.decode_datagram(cut).fault == "truncated"
    nxt = rx.decode_datagram(frame)
    assert nxt.fault is None and nxt.messages[0].command == 400


def _is_signaling_nan_bits(value: int) -> bool:
    bits = value & 0xFFFFFFFF
    return (bits >> 23) & 0xFF == 0xFF and bits & 0x7FFFFF != 0 and not bits & 0x400000


# Known limit (found by this test): an int whose bits form a *signaling* NaN float32 is
# quieted by any float32 -> Python float conversion (pymavlink's too), so it cannot survive
# bytewise encoding in Python. No PX4 parameter we expose can take such a value.
@given(st.integers(-(2**31), 2**31 - 1).filter(lambda v: not _is_signaling_nan_bits(v)))
def test_px4_bytewise_int32_round_trip(value: int) -> None:
    t = d.MAV_PARAM_TYPE_INT32
    wire = encode_param_value(value, t, bytewise=True)
    # What actually travels: a float32 on the wire.
    wire = struct.unpack("<f", struct.pack("<f", wire))[0]
    assert decode_param_value(wire, t, bytewise=True) == value


@given(st.integers(-(2**15), 2**15 - 1))
def test_ardupilot_c_cast_int16_round_trip(value: int) -> None:
    t = d.MAV_PARAM_TYPE_INT16
    assert decode_param_value(encode_param_value(value, t, bytewise=False), t, bytewise=False) == value


def test_signed_frames_verify_and_unsigned_are_classified() -> None:
    key = bytes(range(32))
    tx, rx = Codec(255, 190, key), Codec(1, 1, key, allow_unsigned=[d.MAVLINK_MSG_ID_HEARTBEAT])
    cmd = tx.mav.command_long_encode(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
    assert rx.decode_datagram(tx.encode(cmd)).fault is None
    plain = Codec(255, 190)
    assert rx.decode_datagram(plain.encode(cmd)).fault == "unsigned"
    assert rx.decode_datagram(plain.encode(plain.mav.heartbeat_encode(6, 8, 0, 0, 0))).fault is None
    wrong = Codec(255, 191, bytes(32))
    assert rx.decode_datagram(wrong.encode(cmd)).fault == "bad_signature"
