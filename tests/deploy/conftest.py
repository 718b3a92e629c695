"""Fixtures for the agent/world tests: a real policy directory and a SITL run helper."""

from __future__ import annotations

import asyncio
import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import pytest
import torch

from plmarl_sitl.deploy.mqtt.auth import create_key_file
from plmarl_sitl.errors import PolicyFileError
from plmarl_sitl.mission import Mission, load_mission
from plmarl_sitl.sitl.agents import AgentFleet
from plmarl_sitl.sitl.network.broker import free_udp_ports, local_broker
from plmarl_sitl.sitl.world import SitlWorld, WorldConfig, WorldSummary

ROOT = Path(__file__).resolve().parents[2]
MISSION = ROOT / "missions" / "paper_urban.yaml"


@pytest.fixture(scope="session")
def mission() -> Mission:
    return load_mission(MISSION)


@pytest.fixture(scope="session")
def policy_dir(tmp_path_factory: pytest.TempPathFactory, mission: Mission) -> Path:
    """The trained PL-MARL policy if it loads for this mission, else a real untrained one
    (the same export path, random weights), so the agent always runs real TorchScript."""
    from plmarl_sitl.learning.nn.io import load_policy

    trained = ROOT / "policies" / "pl-marl"
    try:
        load_policy(trained, mission)
        return trained
    except PolicyFileError:
        pass
    return make_untrained_policy(tmp_path_factory.mktemp("policy"), mission)


@pytest.fixture(scope="session")
def v2_policy_dir(tmp_path_factory: pytest.TempPathFactory, mission: Mission) -> Path:
    """A real policy of input version 2 (demand map, predicted-in-range f), untrained."""
    return make_untrained_policy(tmp_path_factory.mktemp("policy-v2"), mission)


def make_untrained_policy(out: Path, mission: Mission) -> Path:
    from plmarl_sitl.learning.nn import Actor, BeliefTracker, DeployedPolicy, FeatureScales, make_predictor
    from plmarl_sitl.learning.nn.io import export_policy

    torch.manual_seed(0)
    tracker = BeliefTracker(make_predictor("mlp"), mission.signalling.buffer_len, 1.0)
    actor = Actor()
    for p in actor.parameters():  # non-trivial actions
        torch.nn.init.normal_(p, std=0.3)
    export_policy(out, tracker, DeployedPolicy(actor, *FeatureScales.from_mission(mission)), {"method": "untrained-test", "seed": 0})
    return out


@dataclass
class SitlRun:
    summary: WorldSummary
    fleet: AgentFleet
    metrics: list[dict] = field(default_factory=list)
    events: dict[str, float] = field(default_factory=dict)

    def trace(self, i: int) -> list[dict]:
        return self.fleet.procs[i].trace()

    def stats(self, i: int) -> dict | None:
        return self.fleet.procs[i].stats()

    def log(self, i: int) -> str:
        return self.fleet.procs[i].log()


def run_sitl(
    tmp: Path,
    policy: Path,
    *,
    n: int,
    broker: str = "amqtt",
    personality: str = "px4",
    episode_s: int = 30,
    speedup: float = 10.0,
    tup_s: int | None = None,
    world_mission: Mission | None = None,
    on_second: Callable[[SitlWorld, AgentFleet, dict, SitlRun], None] | None = None,
    wall_timeout_s: float = 90.0,
    publish_sense: bool = True,
) -> SitlRun:
    """World in this process (its own event loop), broker amqtt (in-process) or mosquitto
    (child), n agents as child processes; everything is stopped whatever happens."""
    base = load_mission(MISSION)
    wm = world_mission or dataclasses.replace(base, n_uavs=n)
    if tup_s is not None:
        wm = wm.with_tup(tup_s)

    async def main() -> SitlRun:
        async with local_broker(broker) as b:
            url = b.url
            base_port = free_udp_ports(n)
            fleet = AgentFleet(tmp)
            run = SitlRun(WorldSummary(), fleet)
            run.broker = b  # type: ignore[attr-defined]

            def hook(m: dict) -> None:
                run.metrics.append(m)
                if on_second is not None:
                    on_second(world, fleet, m, run)

            key_path = tmp / "swarm.key"  # signed messages, as `plmarl swarm up` flies them
            key = create_key_file(key_path)
            world = SitlWorld(
                WorldConfig(mission=wm, broker_url=url, personality=personality, speedup=speedup, base_port=base_port, episode_s=episode_s,
                            publish_sense=publish_sense, swarm_key=key),
                on_metrics=hook,
            )
            try:
                await world.start()
                for i in range(n):
                    await fleet.spawn(i, f"udpout://127.0.0.1:{base_port + i}", url, mission=MISSION, policy=policy, n_uavs=n, tup_s=tup_s,
                                      swarm_key=key_path)
                async with asyncio.timeout(wall_timeout_s):
                    run.summary = await world.run()
            finally:
                await world.shutdown(fleet)
        return run

    return asyncio.run(main())
