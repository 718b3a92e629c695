"""Pure unit and property tests: wire schema, filters, neighbour table, guard, URLs."""

from __future__ import annotations

import math
import struct

import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st

from plmarl_sitl.deploy.agent.guard import band_guard
from plmarl_sitl.deploy.agent.neighbours import NeighbourTable
from plmarl_sitl.deploy.mavlink.connect import Endpoint, parse_url
from plmarl_sitl.deploy.mqtt.schema import (
    STATE_SIZE,
    Malformed,
    SeqFilter,
    StateMsg,
    Topics,
    decode_json,
    decode_sense,
    decode_state,
    encode_json,
    encode_sense,
    encode_state,
    split_states,
)
from plmarl_sitl.deploy.mqtt.url import parse_broker_url
from plmarl_sitl.errors import UserError
from plmarl_sitl.mission import Origin
from plmarl_sitl.model.geodesy import geodetic_to_ned, ned_to_geodetic
from plmarl_sitl.model.signalling import Holdings, signalling_update

f32 = st.floats(-1e5, 1e5, width=32)


@given(st.integers(0, 65535), st.integers(0, 65535), st.integers(0, 2**32 - 1), st.integers(-(2**31), 2**31 - 1),
       st.tuples(f32, f32, f32, f32.filter(lambda x: abs(x) < 1e3), f32.filter(lambda x: abs(x) < 1e3), f32.filter(lambda x: abs(x) < 1e3)))
def test_state_round_trip(sender, session, seq, t_ms, state) -> None:
    m = StateMsg(sender, session, seq, t_ms, state)
    raw = encode_state(m)
    assert len(raw) == STATE_SIZE == 39  # kind I (schema 4): 38 + entry count 1 (knowing nothing)
    assert decode_state(raw) == m


@given(st.binary(max_size=80))
def test_garbage_never_crashes(data: bytes) -> None:
    for dec in (decode_state, decode_sense, decode_json):
        try:
            dec(data)
        except Malformed as exc:
            assert exc.reason


def test_malformed_reasons() -> None:
    good = encode_state(StateMsg(1, 2, 3, 15000, (1.0, 2.0, -60.0, 0.0, 0.0, 0.0)))
    assert decode_state(good).t_s == 15.0
    cases = {
        b"": "short",
        bytes([2]) + good[1:]: "version",
        good[:1] + b"U" + good[2:]: "kind",
        good[:-1]: "short",
        good + b"x": "length",
        good[:14] + struct.pack("<f", math.nan) + good[18:]: "not_finite",
        good[:14] + struct.pack("<f", 3e6) + good[18:]: "out_of_range",
    }
    for raw, reason in cases.items():
        with pytest.raises(Malformed) as ei:
            decode_state(raw)
        assert ei.value.reason == reason


def test_sense_and_json() -> None:
    raw = encode_sense(3, 7000, [(1.5, 2.5), (3.0, 4.0)])
    m = decode_sense(raw)
    assert m.receiver == 3 and m.t_ms == 7000 and m.users == ((1.5, 2.5), (3.0, 4.0))
    assert decode_sense(encode_sense(0, 0, [])).users == ()
    with pytest.raises(Malformed):
        decode_sense(raw[:-1])
    assert decode_json(encode_json({"t0_boot_s": 4.0}))["t0_boot_s"] == 4.0
    with pytest.raises(Malformed):
        decode_json(b'{"v": 9}')
    with pytest.raises(Malformed):
        decode_json(b"[1]")


def test_seq_filter() -> None:
    f = SeqFilter()

    def msg(seq: int, t: int, session: int = 1) -> StateMsg:
        return StateMsg(0, session, seq, t, (0.0,) * 6)  # type: ignore[arg-type]

    assert f.check(msg(5, 15000)) is None
    assert f.check(msg(5, 15000)) == "duplicate"
    assert f.check(msg(4, 0)) == "out_of_order"
    assert f.check(msg(6, 30000)) is None
    assert f.check(msg(0, 45000, session=2)) is None  # a restarted sender
    assert f.check(msg(9, 60000, session=1)) is None  # (old session again, newer instant)
    assert f.check(msg(1, 15000, session=3)) == "out_of_order"


def test_topics() -> None:
    t = Topics("s1")
    assert t.tx(3) == "plmarl/s1/tx/3" and t.rx(0) == "plmarl/s1/rx/0" and t.sense(2) == "plmarl/s1/sense/2"
    assert t.id_of("plmarl/s1/tx/12") == 12 and t.id_of(t.metrics) is None


def test_neighbour_table_matches_twin_holdings() -> None:
    """The agent's table follows world.signalling.Holdings exactly, instant by instant."""
    n, drop = 4, 2
    gen = torch.Generator().manual_seed(3)
    h = Holdings.empty((), n, torch.float32)
    tables = [NeighbourTable(n, i, drop) for i in range(n)]
    for k in range(12):
        t = 15.0 * k
        rx = torch.rand(n, n, generator=gen) < 0.6
        state = torch.randn(n, 6, generator=gen) * 100
        h = signalling_update(h, t, rx, state, drop)
        for i, tab in enumerate(tables):
            for j in range(n):
                if j != i and bool(rx[i, j]):
                    tab.on_state(j, t, tuple(state[j].tolist()))
            tab.close_instant(t)
            assert torch.equal(tab.mask(), h.neighbour_mask(drop)[i])
            assert tab.lost == bool(h.lost[i])
            assert torch.equal(tab.t_rx, h.t_rx[i])
            got = h.ever[i]
            assert torch.allclose(tab.state[got], h.state[i][got])


def test_band_guard() -> None:
    # Inside the band and far from the edges: untouched.
    assert band_guard((1.0, 2.0, 0.5), 90.0, 0.0, 40, 150, 5) == (1.0, 2.0, 0.5)
    # Diving at the floor: vertical brake wins, horizontal push dropped.
    an, ae, ad = band_guard((3.0, 3.0, 4.0), 45.0, -8.0, 40, 150, 5)
    assert (an, ae) == (0.0, 0.0) and ad == pytest.approx(-4.5)
    # Below the band: steered back up whatever the policy says.
    assert band_guard((0.0, 0.0, 5.0), 20.0, 0.0, 40, 150, 5)[2] < 0
    # Above the band: steered down.
    assert band_guard((0.0, 0.0, -5.0), 160.0, 0.0, 40, 150, 5)[2] > 0
    # Norm stays within A_max.
    a = band_guard((5.0, 5.0, -3.0), 90.0, 0.0, 40, 150, 5)
    assert math.hypot(*a) <= 5.0 + 1e-9


def test_ned_offset_inverts_geodetic() -> None:
    o = Origin(47.397742, 8.545594, 488.0)
    lat, lon, alt = ned_to_geodetic(o.lat_deg, o.lon_deg, o.alt_m, 500.0, 430.0, 0.0)
    n, e, d = geodetic_to_ned(o.lat_deg, o.lon_deg, o.alt_m, lat, lon, alt)
    assert n == pytest.approx(500.0, abs=1e-6) and e == pytest.approx(430.0, abs=1e-6) and d == pytest.approx(0.0)


def test_urls() -> None:
    assert parse_url("udpout://127.0.0.1:14540") == Endpoint("udpout", "127.0.0.1", 14540)
    assert parse_url("udp://127.0.0.1:14540").scheme == "udpout"
    assert parse_url("udpin://0.0.0.0:14550") == Endpoint("udpin", "0.0.0.0", 14550)
    assert parse_url("tcpout://127.0.0.1:5760") == Endpoint("tcpout", "127.0.0.1", 5760)
    assert parse_url("serial:///dev/ttyACM0:57600") == Endpoint("serial", "/dev/ttyACM0", 57600)
    for bad in ("http://x:1", "udpout://127.0.0.1", "serial:///dev/ttyACM0", "udpout://:5"):
        with pytest.raises(UserError):
            parse_url(bad)
    assert parse_broker_url("mqtt://127.0.0.1:1884") == ("127.0.0.1", 1884)
    assert parse_broker_url("broker.local") == ("broker.local", 1883)
    with pytest.raises(UserError):
        parse_broker_url("http://x")


def test_world_delivers_an_instant_in_one_message_per_receiver_then_closes_it():
    """The SITL link emulator holds an instant's deliveries until every live vehicle has
    signalled, then sends each receiver one rx message with all of them, then `closed`.
    An update for an instant already closed goes out alone at once; an instant a vehicle
    stays silent in is closed after half the agents' wait bound."""
    import asyncio
    import dataclasses

    from plmarl_sitl.deploy.mqtt.schema import (
        INSTANT_WAIT_MIN_S,
        StateMsg,
        Topics,
        decode_json,
        encode_state,
        split_states,
    )
    from plmarl_sitl.deploy.mqtt.transport import MqttBus
    from plmarl_sitl.mission import load_mission
    from plmarl_sitl.sitl.network.broker import EmbeddedBroker
    from plmarl_sitl.sitl.world import SitlWorld, WorldConfig

    from .conftest import MISSION

    topics = Topics("sitl")
    seen: list[tuple[str, bytes]] = []

    def tx(sender: int, t_s: int = 15, seq: int = 1) -> tuple[str, bytes]:
        return topics.tx(sender), encode_state(StateMsg(sender, 7, seq, t_s * 1000, (40.0 * sender, 0.0, -60.0, 0.0, 0.0, 0.0)))

    def senders(payload: bytes) -> list[int]:
        return [decode_state(part).sender for part in split_states(payload)]

    async def until(cond) -> None:  # noqa: ANN001
        while not cond():
            await asyncio.sleep(0.02)

    def closings() -> list[float]:
        return [decode_json(p)["t_s"] for t, p in seen if t == topics.closed]

    async def main() -> None:
        async with EmbeddedBroker() as broker:
            mission = dataclasses.replace(load_mission(MISSION), n_uavs=3)
            world = SitlWorld(WorldConfig(mission=mission, broker_url=broker.url, base_port=40000))
            listener = MqttBus(broker.url, "listener", [topics.rx("+"), topics.closed], lambda t, p: seen.append((t, p)))
            tasks = [asyncio.create_task(world.bus.run()), asyncio.create_task(listener.run())]
            try:
                async with asyncio.timeout(10):
                    await world.bus.connected.wait()
                    await listener.connected.wait()
                    world.relay.on_message(*tx(0))
                    world.relay.on_message(*tx(1))
                    await asyncio.sleep(0.3)
                    assert seen == []  # held until the instant closes
                    world.relay.on_message(*tx(2))  # the last live vehicle signals
                    await until(lambda: closings())
                    batch = seen[:-1]
                    assert [t for t, _ in seen[-1:]] == [topics.closed] and closings() == [15.0]
                    rx = {topics.id_of(t): senders(p) for t, p in batch}
                    assert len(rx) == len(batch) == 3  # one message per receiver (all within 80 m)
                    assert all(sorted(v) == sorted({0, 1, 2} - {i}) for i, v in rx.items())
                    # The same message again is a replay: counted, not relayed.
                    world.relay.on_message(*tx(0))
                    assert world.links.counters.replayed == 1
                    # Late for instant 15: delivered alone, and no second closing.
                    n = len(seen)
                    world.relay.on_message(*tx(0, seq=2))
                    await until(lambda: len(seen) == n + 2)
                    assert all(senders(p) == [0] for _, p in seen[n:]) and closings() == [15.0]
                    # Vehicle 2 stays silent at instant 30: closed once the bound has passed.
                    world.time.t0, n = 0.0, len(seen)
                    world.relay.on_message(*tx(0, 30, seq=3))
                    world.relay.on_message(*tx(1, 30, seq=2))
                    world.host.now = 30.0 + 0.5 * INSTANT_WAIT_MIN_S
                    world.relay.close_overdue()
                    await asyncio.sleep(0.3)
                    assert len(seen) == n
                    world.host.now = 30.0 + INSTANT_WAIT_MIN_S
                    world.relay.close_overdue()
                    await until(lambda: closings() == [15.0, 30.0])
                    late = {topics.id_of(t): sorted(senders(p)) for t, p in seen[n:] if t != topics.closed}
                    assert late == {0: [1], 1: [0], 2: [0, 1]}
            finally:
                for t in tasks:
                    t.cancel()
                await asyncio.gather(*tasks, return_exceptions=True)

    asyncio.run(main())


@given(st.lists(st.tuples(st.integers(0, 19), st.integers(0, 2**31 - 1)), min_size=1, max_size=20))
def test_rx_batches_split_into_their_messages(parts) -> None:
    msgs = [StateMsg(s, 1, seq, 15_000, (1.0, 2.0, -60.0, 0.0, 0.0, 0.0)) for s, seq in parts]
    payload = b"".join(encode_state(m) for m in msgs)
    assert [decode_state(p) for p in split_states(payload)] == msgs


def test_a_batch_that_is_not_whole_messages_is_malformed() -> None:
    good = encode_state(StateMsg(1, 2, 3, 15000, (1.0, 2.0, -60.0, 0.0, 0.0, 0.0)))
    with pytest.raises(Malformed) as exc:
        split_states(good + good[:10])
    assert exc.value.reason == "length"
    assert split_states(good[:5]) == [good[:5]]  # short: decode_state names the reason
