"""The agent as a composition, without a broker or an autopilot: a bus that records what is
published and a link whose autopilot never answers stand in for the real ones (the SITL
tests fly it with both)."""

from __future__ import annotations

import asyncio
import dataclasses
import json
import math
from pathlib import Path

import pytest

from plmarl_sitl.deploy.agent.config import AgentConfig
from plmarl_sitl.deploy.agent.core import Agent
from plmarl_sitl.deploy.mavlink.personality import personality
from plmarl_sitl.deploy.mqtt.schema import StateMsg, decode_state, encode_json, encode_sense, encode_state
from plmarl_sitl.deploy.mqtt.transport import BusStats
from plmarl_sitl.errors import UserError
from plmarl_sitl.learning.nn.io import load_policy
from plmarl_sitl.mission import load_mission

from .conftest import MISSION


class RecordingBus:
    def __init__(self) -> None:
        self.stats = BusStats()
        self.sent: list[tuple[str, bytes]] = []

    def publish(self, topic: str, payload: bytes, *, retain: bool = False, sticky: bool = False) -> bool:
        self.sent.append((topic, payload))
        return True

    async def run(self) -> None:
        await asyncio.Event().wait()  # serves until cancelled


class SilentLink:
    """An autopilot that never sends a heartbeat."""

    personality = None
    latest: dict = {}
    sysid = 1
    is_open = True

    def __init__(self) -> None:
        self.closed = False

    async def open(self, timeout: float = 5.0) -> None:
        await asyncio.Event().wait()

    def close(self) -> None:
        self.closed = True

    def send_heartbeat(self) -> None:
        pass


@dataclasses.dataclass
class Telemetry:  # the LOCAL_POSITION_NED fields the agent reads
    time_boot_ms: int
    x: float = 0.0
    y: float = 0.0
    z: float = -60.0
    vx: float = 0.0
    vy: float = 0.0
    vz: float = 0.0


def make_agent(policy_dir: Path, n: int = 3, **cfg: object) -> tuple[Agent, RecordingBus, SilentLink]:
    mission = dataclasses.replace(load_mission(MISSION), n_uavs=n)
    bus, link = RecordingBus(), SilentLink()
    config = AgentConfig(uav_id=0, connect_url="udpout://127.0.0.1:14540", mission=mission, **cfg)  # type: ignore[arg-type]
    return Agent(config, load_policy(policy_dir, mission), bus, link), bus, link


def test_an_id_outside_the_mission_is_a_user_error() -> None:
    with pytest.raises(UserError, match="--id 3: the mission has 3 UAVs"):
        AgentConfig(uav_id=3, connect_url="udpout://127.0.0.1:14540", mission=dataclasses.replace(load_mission(MISSION), n_uavs=3))


def test_agent_counts_and_drops_bad_control_payloads(policy_dir: Path) -> None:
    """Malformed `closed`, `start`, `ctl` and sensing payloads are counted by reason and
    change nothing; a good `closed` moves the agent's closed instant forward only."""
    agent, _, _ = make_agent(policy_dir)
    t, inbox = agent.topics, agent.inbox
    for topic, payload in [(t.closed, b"{not json"), (t.closed, encode_json({"t_s": "x"})), (t.closed, b'{"t_s": 3}'),
                           (t.start, b"\x00\x01"), (t.ctl, encode_json({})), (t.sense(0), b"\x01")]:
        inbox.on_message(topic, payload)
    assert agent.clock.closed_t == -math.inf and agent.clock.t0 is None and not agent.decision.sense_history
    assert inbox.rx.reasons.get("closed") == 3 and inbox.rx.reasons.get("start") == 1 and inbox.rx.reasons.get("ctl") == 1
    assert any(r.startswith("sense_") for r in inbox.rx.reasons)
    inbox.on_message(t.closed, encode_json({"t_s": 15}))
    inbox.on_message(t.closed, encode_json({"t_s": 0}))  # an old instant does not move it back
    assert agent.clock.closed_t == 15.0


def test_agent_keeps_the_good_messages_of_a_batch_with_a_bad_one(policy_dir: Path) -> None:
    agent, _, _ = make_agent(policy_dir)
    inbox = agent.inbox
    good = encode_state(StateMsg(1, 7, 1, 15_000, (40.0, 0.0, -60.0, 0.0, 0.0, 0.0)))
    bad = b"\x09" + encode_state(StateMsg(2, 7, 1, 15_000, (80.0, 0.0, -60.0, 0.0, 0.0, 0.0)))[1:]  # wrong version
    inbox.on_message(agent.topics.rx(0), good + bad)
    assert inbox.rx.accepted == 1 and inbox.rx.reasons.get("version") == 1
    assert float(agent.table.t_rx[1]) == 15.0 and float(agent.table.t_rx[2]) < 0
    inbox.on_message(agent.topics.rx(0), good + bad[:20])  # not whole messages: dropped whole
    assert inbox.rx.reasons.get("length") == 1 and inbox.rx.accepted == 1


def test_agent_signals_at_each_instant_and_decides_every_tau(policy_dir: Path) -> None:
    """From the world's start, telemetry drives the clock: the state goes to tx/<id> at
    instants 0 and 15 (consecutive seq, this agent's session) and the policy runs every
    tau = 3 s, each second processed once."""
    agent, bus, _ = make_agent(policy_dir)
    t = agent.topics
    agent.inbox.on_message(t.start, encode_json({"t0_boot_s": 2.0, "n_uavs": 3}))
    agent.inbox.on_message(t.sense(0), encode_sense(0, 0, [(10.0, 20.0)]))
    for ms in range(0, 17_900, 100):  # mission seconds 0..15 (boot 2.0 .. 17.8)
        agent.on_telemetry(Telemetry(ms, x=ms / 1000.0))
    states = [decode_state(p) for topic, p in bus.sent if topic == t.tx(0)]
    assert [(m.t_ms, m.seq, m.session, m.sender) for m in states] == [(0, 0, agent.cfg.session_id, 0),
                                                                       (15_000, 1, agent.cfg.session_id, 0)]
    assert states[0].state[0] == pytest.approx(2.0)  # the telemetry at the instant
    assert agent.stats.seconds == 16 and agent.stats.decisions == 6
    assert agent.decision.used_sense_t == 0.0


def test_agent_stopped_before_the_autopilot_answers_writes_its_counters(policy_dir: Path, tmp_path: Path) -> None:
    """Stop during start-up: exit 0, the link closed, no stop mode commanded (the vehicle
    was never flown), and the stats file carries the inbox's counters by reason."""
    stats = tmp_path / "stats.json"
    agent, _, link = make_agent(policy_dir, stats_path=stats)
    agent.inbox.on_message(agent.topics.closed, b"{not json")
    agent.inbox.on_message(agent.topics.rx(0), b"\x01\x02")

    async def main() -> int:
        run = asyncio.ensure_future(agent.run())
        await asyncio.sleep(0.2)
        agent.stop_event.set()
        return await run

    assert asyncio.run(main()) == 0
    assert link.closed
    out = json.loads(stats.read_text())
    assert out["rx"] == agent.inbox.rx.as_dict() and out["rx"]["malformed"] == 2 and out["rx"]["malformed_closed"] == 1
    assert out["bus"] == BusStats().as_dict() and out["dropped"] == [] and out["reengaged"] == 0 and out["fail"] is False
    assert out["seconds"] == 0 and out["startup_s"] is None


def test_the_stop_mode_comes_from_the_personality() -> None:
    assert personality("ardupilot").stop_mode == "BRAKE"
    assert personality("px4").stop_mode == personality("px4").hold_mode
