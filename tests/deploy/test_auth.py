"""Signed signalling (schema version 2, issue 14): the key files, the trailer, the wire, and
what an agent's inbox does with forged, replayed, stale and mis-attributed messages."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from plmarl_sitl.deploy.mqtt.auth import AuthError, SwarmKey, create_key_file, key_from_flags, load_key
from plmarl_sitl.deploy.mqtt.credentials import load_credentials, write_credentials
from plmarl_sitl.deploy.mqtt.schema import STATE_SIZE, Malformed, StateMsg, encode_json, encode_state
from plmarl_sitl.deploy.mqtt.wire import Wire
from plmarl_sitl.errors import UserError

from .test_agent import Telemetry, make_agent

KEY = SwarmKey(bytes(range(32)))
OTHER = SwarmKey(bytes(range(1, 33)))


def state(sender: int = 1, seq: int = 1, t_s: int = 15, session: int = 7, pos: float = 40.0) -> StateMsg:
    return StateMsg(sender, session, seq, t_s * 1000, (pos, 0.0, -60.0, 0.0, 0.0, 0.0))


# ---------------------------------------------------------------------------- the trailer
def test_a_sealed_message_opens_only_under_its_key_and_domain() -> None:
    sealed = KEY.seal(b"S", b"hello")
    assert len(sealed) == 5 + 9 and KEY.open(b"S", sealed) == b"hello"
    with pytest.raises(AuthError, match="forged"):
        KEY.open(b"ctl", sealed)  # a tag made for a state never passes for a ctl
    with pytest.raises(AuthError, match="wrong_key"):
        OTHER.open(b"S", sealed)
    for i in range(len(sealed)):  # any one bit flipped anywhere
        flipped = bytearray(sealed)
        flipped[i] ^= 0x01
        with pytest.raises(AuthError):
            KEY.open(b"S", bytes(flipped))
    with pytest.raises(AuthError, match="forged"):
        KEY.open(b"S", b"\x01" * 9)


# ---------------------------------------------------------------------------- key files
def test_key_files_are_private_and_checked(tmp_path: Path) -> None:
    path = tmp_path / "swarm.key"
    key = create_key_file(path)
    assert stat.S_IMODE(path.stat().st_mode) == 0o600 and load_key(path) == key
    os.chmod(path, 0o640)
    with pytest.raises(UserError, match=r"--swarm-key .*accessible to others \(mode 640\)"):
        load_key(path)
    os.chmod(path, 0o600)
    path.write_text("00" * 31 + "\n")
    with pytest.raises(UserError, match="not a key file"):
        load_key(path)
    with pytest.raises(UserError, match="cannot read the key file"):
        load_key(tmp_path / "missing.key")
    with pytest.raises(UserError, match="no --swarm-key FILE"):
        key_from_flags(None, no_auth=False)
    assert key_from_flags(None, no_auth=True) is None


def test_credentials_files(tmp_path: Path) -> None:
    path = tmp_path / "agent0.cred"
    write_credentials(path, "agent0", "s3cret")
    assert stat.S_IMODE(path.stat().st_mode) == 0o600 and load_credentials(path) == ("agent0", "s3cret")
    path.write_text("agent0\n")
    with pytest.raises(UserError, match="USERNAME:PASSWORD"):
        load_credentials(path)


# ---------------------------------------------------------------------------- the wire
def test_signed_wire_round_trips_and_refuses_version_1() -> None:
    wire, plain = Wire(KEY), Wire(None)
    m = state()
    signed = wire.state(m)
    assert len(signed) == wire.state_size == STATE_SIZE + 9 and signed[0] == 2
    assert wire.read_state(signed) == m
    assert wire.split_states(signed + signed) == [signed, signed]
    with pytest.raises(AuthError, match="unsigned"):
        wire.read_state(encode_state(m))
    with pytest.raises(Malformed, match="version"):
        plain.read_state(signed)  # an unsigned receiver cannot read a signed swarm: counted, not guessed
    assert wire.read_json("ctl", wire.json("ctl", {"tup_s": 30, "seq": 1})) == {"v": 2, "tup_s": 30, "seq": 1}
    with pytest.raises(AuthError, match="unsigned"):
        wire.read_json("ctl", encode_json({"tup_s": 45}))
    with pytest.raises(AuthError, match="forged"):
        wire.read_json("ctl", wire.json("start", {"t0_boot_s": 1.0}))
    sense = wire.sense(2, 15_000, [(1.0, 2.0)])
    assert wire.read_sense(sense).users == ((1.0, 2.0),)
    assert wire.read_demand(wire.demand(3, 30_000, 100.0, 2, 2, [0, 5, 0, 1])).cells == ((1, 5), (3, 1))


# ---------------------------------------------------------------------------- the agent's inbox
def started_agent(policy_dir: Path, **cfg: object):  # noqa: ANN201
    """Agent 0 of 3 with the swarm key, its mission started at boot 0 and its clock at t = 16 s."""
    agent, bus, _ = make_agent(policy_dir, swarm_key=KEY, **cfg)
    agent.inbox.on_message(agent.topics.start, Wire(KEY).json("start", {"t0_boot_s": 0.0, "n_uavs": 3}))
    agent.on_telemetry(Telemetry(16_000))
    return agent, bus


def test_the_agent_signs_what_it_sends(policy_dir: Path) -> None:
    agent, bus = started_agent(policy_dir)
    sent = [p for t, p in bus.sent if t == agent.topics.tx(0)]
    assert [Wire(KEY).read_state(p).t_ms for p in sent] == [0, 15_000]  # instants 0 and 15 (the clock jumped to 16)
    with pytest.raises(AuthError):
        Wire(OTHER).read_state(sent[0])


def test_forged_replayed_stale_and_misattributed_states_change_nothing(policy_dir: Path) -> None:
    """The attack of issue 14 on the inbox: each bad message is dropped, counted under its
    reason, and leaves the held states (what the tracker turns into beliefs) untouched."""
    agent, _ = started_agent(policy_dir)
    inbox, t, wire = agent.inbox, agent.topics, Wire(KEY)
    good = wire.state(state(1, seq=1, t_s=15))
    inbox.on_message(t.rx(0), good)
    assert inbox.rx.accepted == 1
    held = (agent.table.state.clone(), agent.table.t_rx.clone())

    def unchanged() -> bool:
        return bool((agent.table.state == held[0]).all() and (agent.table.t_rx == held[1]).all())

    forged_state = state(1, seq=99, t_s=16, session=0xBEEF, pos=10.0)
    attacks = {
        "forged": Wire(OTHER).state(forged_state)[:-9] + bytes((KEY.key_id,)) + b"\0" * 8,  # our key id, a made-up tag
        "wrong_key": Wire(OTHER).state(forged_state),
        "unsigned": encode_state(forged_state),  # the attacker: version 1, no trailer
        "duplicate": good,  # a replay of the accepted message
        "out_of_window": wire.state(state(2, seq=5, t_s=-45)),  # signed, a minute old (a recorded message)
    }
    for counter, payload in attacks.items():
        inbox.on_message(t.rx(0), payload)
        assert getattr(inbox.rx, counter) == 1, (counter, inbox.rx.as_dict())
        assert unchanged(), counter
    too_new = wire.state(state(2, seq=6, t_s=16 + 30))
    inbox.on_message(t.rx(0), too_new)
    assert inbox.rx.out_of_window == 2 and unchanged()
    assert inbox.rx.accepted == 1 and inbox.rx.malformed == 0
    assert inbox.rx.as_dict()["auth_state_forged"] == 1


def test_direct_bus_drops_a_state_that_claims_another_sender(policy_dir: Path) -> None:
    """--bus direct: a state on tx/2 must be UAV 2's, even when signed (a swarm member
    speaking for another, or a relayed copy on the wrong topic)."""
    agent, _ = started_agent(policy_dir, bus_mode="direct")
    inbox, t, wire = agent.inbox, agent.topics, Wire(KEY)
    inbox.on_message(t.tx(2), wire.state(state(1, seq=1, t_s=15)))
    assert inbox.rx.misattributed == 1 and inbox.rx.accepted == 0
    inbox.on_message(t.tx(1), wire.state(state(1, seq=1, t_s=15)))
    assert inbox.rx.accepted == 1
    inbox.on_message(t.sense(0), wire.sense(1, 15_000, [(1.0, 1.0)]))  # sensing of another vehicle
    assert inbox.rx.misattributed == 2 and not agent.decision.sense_history


def test_forged_or_replayed_ctl_does_not_change_tup(policy_dir: Path) -> None:
    """The retained `ctl` with tup_s 45 of the issue: unsigned, forged or replayed, T_up stays."""
    agent, _ = started_agent(policy_dir)
    inbox, t, wire = agent.inbox, agent.topics, Wire(KEY)
    tup = agent.clock.tup
    inbox.on_message(t.ctl, encode_json({"tup_s": 45}))
    inbox.on_message(t.ctl, Wire(OTHER).json("ctl", {"tup_s": 45, "seq": 1}))
    inbox.on_message(t.ctl, wire.json("start", {"tup_s": 45, "seq": 1}))  # a start's tag on a ctl
    assert agent.clock.tup == tup
    assert (inbox.rx.unsigned, inbox.rx.wrong_key, inbox.rx.forged) == (1, 1, 1)
    assert inbox.rx.as_dict()["auth_ctl_unsigned"] == 1
    real = wire.json("ctl", {"tup_s": 30, "seq": 1})
    inbox.on_message(t.ctl, real)
    assert agent.clock.tup == 30
    inbox.on_message(t.ctl, wire.json("ctl", {"tup_s": 5, "seq": 2}))
    inbox.on_message(t.ctl, real)  # the older order again
    assert agent.clock.tup == 5 and inbox.rx.out_of_order == 1


def test_unsigned_start_and_closed_are_refused(policy_dir: Path) -> None:
    agent, _, _ = make_agent(policy_dir, swarm_key=KEY)
    t = agent.topics
    agent.inbox.on_message(t.start, encode_json({"t0_boot_s": 2.0, "n_uavs": 3}))
    agent.inbox.on_message(t.closed, encode_json({"t_s": 15}))
    assert agent.clock.t0 is None and agent.clock.closed_t < 0 and agent.inbox.rx.unsigned == 2
