"""The demand message (docs/SIGNALLING.md, schema version 2): codec round trip, fuzzing,
malformed payloads counted by the agent and dropped, newer map_seq wins, and the cells a
policy gets equal the twin's map."""

from __future__ import annotations

import collections
import dataclasses
import struct

import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from plmarl_sitl.deploy.agent.clock import MissionClock
from plmarl_sitl.deploy.agent.demand import DemandMaps
from plmarl_sitl.deploy.agent.inbox import Inbox, subscriptions
from plmarl_sitl.deploy.agent.neighbours import NeighbourTable
from plmarl_sitl.deploy.mqtt.demand import HEAD_SIZE, decode_demand, encode_demand, seq_newer
from plmarl_sitl.deploy.mqtt.schema import Malformed, Topics
from plmarl_sitl.learning.nn import Actor, DeployedPolicy, FeatureScales
from plmarl_sitl.learning.nn.io import script
from plmarl_sitl.mission import load_mission
from plmarl_sitl.model.demand import cell_centres, demand_cells, demand_map, grid_shape, is_map_instant, map_period
from plmarl_sitl.twin.env import CoverageEnv

from .conftest import MISSION

M = load_mission(MISSION)
ROWS, COLS = grid_shape(M.area.north_m, M.area.east_m, M.demand.cell_m)


@st.composite
def maps(draw):  # noqa: ANN001, ANN201
    rows, cols = draw(st.integers(1, 12)), draw(st.integers(1, 12))
    counts = draw(st.lists(st.integers(0, 65535) | st.just(0), min_size=rows * cols, max_size=rows * cols))
    return draw(st.integers(0, 65535)), draw(st.integers(0, 2**31 - 1)), draw(st.floats(1.0, 1e4, width=32)), rows, cols, counts


@settings(max_examples=200, deadline=None)
@given(maps())
def test_round_trip(m) -> None:  # noqa: ANN001
    seq, t_ms, cell_m, rows, cols, counts = m
    msg = decode_demand(encode_demand(seq, t_ms, cell_m, rows, cols, counts))
    assert (msg.map_seq, msg.t_ms, msg.cell_m, msg.rows, msg.cols) == (seq, t_ms, cell_m, rows, cols)
    assert msg.cells == tuple((i, c) for i, c in enumerate(counts) if c)  # nonzero cells only, in order


@settings(max_examples=500, deadline=None)
@given(st.binary(max_size=200))
def test_garbage_never_raises_anything_but_malformed(data: bytes) -> None:
    for payload in (data, bytes([1, ord("D")]) + data):
        try:
            decode_demand(payload)
        except Malformed:
            pass


@settings(max_examples=150, deadline=None)
@given(maps(), st.data())
def test_a_damaged_map_is_malformed_or_still_a_valid_map(m, data) -> None:  # noqa: ANN001
    """Flip, cut or extend a valid payload anywhere: the decoder either rejects it with
    a reason or returns a map whose cells are inside its grid, nonzero and in order."""
    good = bytearray(encode_demand(*m))
    op = data.draw(st.sampled_from(["flip", "cut", "extend"]))
    if op == "flip":
        i = data.draw(st.integers(0, len(good) - 1))
        good[i] ^= data.draw(st.integers(1, 255))
    elif op == "cut":
        good = good[: data.draw(st.integers(0, len(good) - 1))]
    else:
        good += data.draw(st.binary(min_size=1, max_size=9))
    try:
        msg = decode_demand(bytes(good))
    except Malformed as exc:
        assert exc.reason in {"short", "version", "kind", "length", "grid", "cells"}
        return
    idx = [i for i, _ in msg.cells]
    assert idx == sorted(set(idx)) and all(0 <= i < msg.rows * msg.cols for i in idx) and all(c > 0 for _, c in msg.cells)


def test_malformed_reasons() -> None:
    ok = encode_demand(3, 30_000, 100.0, 2, 2, [0, 5, 0, 7])
    assert decode_demand(ok).cells == ((1, 5), (3, 7))
    head = struct.Struct("<BBHifHHH")

    def cells(*pairs: tuple[int, int]) -> bytes:
        return b"".join(struct.pack("<HH", i, c) for i, c in pairs)

    cases = {
        b"": "short",
        b"\x01": "short",
        b"\x02D" + ok[2:]: "version",
        b"\x01S" + ok[2:]: "kind",
        ok[:HEAD_SIZE - 1]: "short",
        ok[:-1]: "length",
        ok + b"\x00": "length",
        head.pack(1, ord("D"), 0, 0, float("nan"), 2, 2, 0): "grid",
        head.pack(1, ord("D"), 0, 0, -100.0, 2, 2, 0): "grid",
        head.pack(1, ord("D"), 0, 0, 100.0, 0, 2, 0): "grid",
        head.pack(1, ord("D"), 0, -1000, 100.0, 2, 2, 0): "grid",
        head.pack(1, ord("D"), 0, 0, 100.0, 2, 2, 1) + cells((4, 1)): "cells",  # outside the grid
        head.pack(1, ord("D"), 0, 0, 100.0, 2, 2, 2) + cells((1, 1), (1, 2)): "cells",  # repeated
        head.pack(1, ord("D"), 0, 0, 100.0, 2, 2, 2) + cells((2, 1), (1, 2)): "cells",  # unordered
        head.pack(1, ord("D"), 0, 0, 100.0, 2, 2, 1) + cells((0, 0)): "cells",  # a zero cell
    }
    for payload, reason in cases.items():
        try:
            decode_demand(payload)
        except Malformed as exc:
            assert exc.reason == reason, (payload, exc.reason)
        else:
            raise AssertionError(f"accepted {payload!r}")


def test_map_seq_wraps() -> None:
    assert seq_newer(1, 0) and not seq_newer(0, 1) and not seq_newer(5, 5)
    assert seq_newer(0, 65535) and seq_newer(10, 65530) and not seq_newer(65530, 10)


def _inbox() -> tuple[Inbox, DemandMaps]:
    topics = Topics()
    maps = DemandMaps(M, topics.demand)
    inbox = Inbox(topics, 0, 4, NeighbourTable(4, 0, 2), MissionClock(15, 3, 0.1, 0.15), collections.deque(),
                  maps, wait_start=True)
    return inbox, maps


def _payload(seq: int, t_s: int, users: torch.Tensor) -> bytes:
    counts = demand_map(users, M.area.north_m, M.area.east_m, M.demand.cell_m)
    return encode_demand(seq, t_s * 1000, M.demand.cell_m, ROWS, COLS, counts.long().tolist())


def test_agent_counts_bad_maps_drops_stale_ones_and_uses_the_newest_not_after_the_decision() -> None:
    inbox, maps = _inbox()
    topic = Topics().demand
    assert topic == "plmarl/sitl/demand" and topic in subscriptions(Topics(), 0, "world") + subscriptions(Topics(), 0, "direct")
    users = torch.rand(240, 2) * 1000.0
    inbox.on_message(topic, b"")  # the world clearing a retained map: nothing
    for bad in (b"\x01", b"\x01D" + b"\x00" * 30, b"\x07D" + b"\x00" * 16):
        inbox.on_message(topic, bad)
    assert inbox.rx.malformed == 3 and maps.accepted == 0
    assert inbox.rx.as_dict()["malformed_demand_short"] == 1 and inbox.rx.as_dict()["malformed_demand_version"] == 1
    assert inbox.rx.as_dict()["malformed_demand_length"] == 1
    assert maps.for_decision(3) is None
    inbox.on_message(topic, _payload(0, 0, users))
    inbox.on_message(topic, _payload(1, 30, users + 5.0))  # the world publishes a map a second ahead
    inbox.on_message(topic, _payload(1, 30, users + 5.0))  # a repeated (retained) one
    inbox.on_message(topic, _payload(0, 0, users))  # an older one
    assert maps.accepted == 2 and maps.stale == 2 and inbox.rx.malformed == 3
    t, cells = maps.for_decision(27)
    assert t == 0.0 and torch.equal(cells[:, 2].sum(), torch.tensor(240.0))
    assert maps.for_decision(30)[0] == 30.0 and maps.late == 0
    assert not maps.awaiting(30) and maps.awaiting(60) and not maps.awaiting(57)
    assert maps.for_decision(60)[0] == 30.0 and maps.late == 1  # due at 60, not here: counted


def test_agent_cells_are_the_twins_map_and_give_the_same_action() -> None:
    """The sparse cells an agent builds from the message are the nonzero rows of the twin's
    published map, and the policy's action is the same with either (empty cells add nothing,
    up to float rounding in the order of the sums)."""
    env = CoverageEnv(dataclasses.replace(M, n_uavs=4), 1, seed=3)
    twin = env.published_demand()[0]
    _, maps = _inbox()
    maps.on_message(decode_demand(_payload(0, 0, env.users.xy[0])))
    _, cells = maps.for_decision(0)
    assert torch.equal(cells, twin[twin[:, 2] > 0])
    torch.manual_seed(0)
    actor = Actor()
    for p in actor.parameters():
        torch.nn.init.normal_(p, std=0.3)
    pol = script(DeployedPolicy(actor, *FeatureScales.from_mission(M)))
    obs = env.observe()
    for i in range(4):
        args = (obs.ego[0, i], obs.nbr_state[0, i], obs.nbr_mask[0, i], obs.sense[0, i], torch.tensor(False))
        assert torch.allclose(pol(*args, cells), pol(*args, twin), rtol=0.0, atol=1e-5)  # float rounding only
    assert pol(*args, cells[:0]).shape == (3,)  # an empty map (no users) is a valid input


def test_map_instants_are_where_the_twin_refreshes() -> None:
    env = CoverageEnv(dataclasses.replace(M, n_uavs=4), 1, seed=0)
    refreshed, last = [], None
    while not env.done:
        if env.t % M.timing.decision_every_s == 0:
            env.observe()
            if env.demand_t != last:
                refreshed.append(env.t)
                last = env.demand_t
        env.physics_step(torch.zeros(1, 4, 3))
    want = [t for t in range(env.horizon) if is_map_instant(t, M.demand.refresh_s, M.timing.decision_every_s)]
    assert refreshed == want and map_period(M.demand.refresh_s, M.timing.decision_every_s) == 30
    assert map_period(20, 3) == 21 and map_period(3, 3) == 3 and map_period(1, 5) == 5
    assert torch.equal(demand_cells(torch.ones(ROWS * COLS), cell_centres(M.area.north_m, M.area.east_m, M.demand.cell_m))[:, :2],
                       cell_centres(M.area.north_m, M.area.east_m, M.demand.cell_m))
