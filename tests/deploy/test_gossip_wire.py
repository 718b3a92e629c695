"""Schema version 4 (issue 24): state messages of kind 'I' carry the sender's knowledge of
failures (failed-set bitmask, plan epoch, and the incarnations above 0); kind 'G' (schema
3) and 'S' (schema 1-2) messages still parse (every incarnation 0; 'S' knowing nothing),
alone or mixed in one rx batch, signed or not; the neighbour table merges what the
accepted states carry (model/gossip.py)."""

from __future__ import annotations

import struct

import pytest

from plmarl_sitl.deploy.agent.neighbours import NeighbourTable
from plmarl_sitl.deploy.mqtt.auth import SwarmKey
from plmarl_sitl.deploy.mqtt.schema import (
    SCHEMA_VERSION,
    STATE_SIZE,
    Malformed,
    StateMsg,
    decode_state,
    encode_state,
    failed_mask,
    split_states,
)
from plmarl_sitl.deploy.mqtt.wire import Wire
from plmarl_sitl.model.knowledge import Known

STATE = (100.0, 200.0, -80.0, 1.0, -2.0, 0.0)


def old_state(sender: int, t_ms: int) -> bytes:
    """A schema-2 state message, byte for byte as a schema-2 agent sends it (kind 'S', 38 bytes)."""
    return struct.pack("<BBHHIi6f", 1, ord("S"), sender, 7, 3, t_ms, *STATE)


def schema_3_state(sender: int, t_ms: int, failed: int, epoch_s: int) -> bytes:
    """A schema-3 state message, byte for byte as a schema-3 agent sends it (kind 'G', 74 bytes)."""
    return struct.pack("<BBHHIi6fI32s", 1, ord("G"), sender, 7, 3, t_ms, *STATE, epoch_s, failed.to_bytes(32, "little"))


def test_gossip_state_round_trip_with_the_largest_ids() -> None:
    assert SCHEMA_VERSION == 4
    m = StateMsg(4, 7, 3, 135_000, STATE)
    raw = encode_state(m)
    assert len(raw) == STATE_SIZE == 39 and raw[1] == ord("I") and decode_state(raw) == m
    known = Known({0: 105, 5: 120, 255: 4_000_000_000}, {0: 1, 5: 3, 249: 65535})
    m = StateMsg.with_knowledge(4, 7, 3, 135_000, STATE, known)
    raw = encode_state(m)
    assert len(raw) == 39 + 7 * 4
    got = decode_state(raw)
    assert got == m and got.known() == known and got.failed_ids() == [0, 5, 255]


def test_a_schema_3_state_still_parses_with_incarnations_0() -> None:
    got = decode_state(schema_3_state(2, 15_000, failed_mask([1, 3]), 15))
    assert got.known() == Known({1: 15, 3: 15})  # every declaration at its epoch


def test_a_schema_3_receiver_counts_a_schema_4_state_as_a_wrong_kind() -> None:
    """The schema-3 decoder's rule (its kinds 'S' and 'G' only), byte for byte: 'I' is malformed_kind."""
    raw = encode_state(StateMsg(1, 7, 3, 15_000, STATE, ((3, 1, 15),)))
    assert raw[1] not in (ord("S"), ord("G"))


def test_bad_incarnation_lists_are_malformed() -> None:
    good = encode_state(StateMsg(1, 7, 3, 15_000, STATE, ((2, 1, 0), (3, 1, 15))))
    for bad, reason in ((good[:-1], "length"), (good[:-7] + bytes(7), "knowledge"),  # an empty entry
                        (good[:-7] + good[-14:-7], "knowledge"),  # identity 2 twice
                        (good + b"\x00", "length")):
        with pytest.raises(Malformed) as exc:
            decode_state(bad)
        assert exc.value.reason == reason


def test_a_schema_2_state_still_parses_as_knowing_nothing() -> None:
    got = decode_state(old_state(2, 15_000))
    assert got.sender == 2 and got.t_s == 15.0 and got.entries == ()
    assert got.state == pytest.approx(STATE)


def test_mixed_batches_split_by_kind_and_bad_lengths_are_malformed() -> None:
    new = encode_state(StateMsg(1, 7, 3, 15_000, STATE, ((0, 2, 0), (3, 0, 15), (4, 1, 0))))
    old = old_state(2, 15_000)
    g = schema_3_state(3, 15_000, failed_mask([5]), 15)
    parts = split_states(old + new + g + old)
    assert parts == [old, new, g, old]
    assert [decode_state(p).failed_ids() for p in parts] == [[], [3], [5], []]
    for bad in (new + new[:20], old + b"\x01"):
        with pytest.raises(Malformed) as exc:
            split_states(bad)
        assert exc.value.reason == "length"
    with pytest.raises(Malformed) as exc:  # an 'I' cut to the length of an 'S' is not an 'S'
        decode_state(new[:38])
    assert exc.value.reason in ("short", "length")
    with pytest.raises(Malformed) as exc:
        decode_state(new[:1] + b"X" + new[2:])
    assert exc.value.reason == "kind"


def test_signed_gossip_states_round_trip_and_batch() -> None:
    wire = Wire(SwarmKey.generate())
    m = StateMsg(1, 7, 3, 30_000, STATE, ((2, 0, 30),))
    signed = wire.state(m)
    assert len(signed) == wire.state_size + 7 == STATE_SIZE + 7 + 9
    assert [wire.read_state(p) for p in wire.split_states(signed + signed)] == [m, m]
    back = StateMsg(2, 7, 4, 30_000, STATE, ((2, 1, 0), (7, 1, 0)))  # two taken back: longer
    signed_back = wire.state(back)
    assert len(signed_back) == STATE_SIZE + 14 + 9
    assert [wire.read_state(p) for p in wire.split_states(signed + signed_back + signed)] == [m, back, m]


def test_the_table_merges_the_knowledge_of_accepted_states() -> None:
    table = NeighbourTable(6, 0, 2)
    assert table.on_state(1, 15.0, STATE, Known({4: 15}))
    assert table.on_state(2, 15.0, STATE, Known({4: 12, 5: 15}))
    assert not table.on_state(1, 0.0, STATE, Known({3: 99}))  # older than held: ignored
    assert table.knowledge.view(before=15) == Known()  # learnt at instant 15: not in 15's own message
    assert table.knowledge.view(before=16) == Known({4: 12, 5: 15})  # the earlier declaration of 4
    # UAV 5 is heard at 30 with a newer incarnation: taken back
    assert table.on_state(3, 30.0, STATE, Known({}, {5: 1}))
    assert table.knowledge.view(before=31) == Known({4: 12}, {5: 1})
    # UAV 4 itself is heard at 45: the declaration of it is refuted (incarnation 1)
    assert table.on_state(4, 45.0, STATE, Known({}))
    assert table.knowledge.view(before=46) == Known({}, {4: 1, 5: 1})
