"""A free-running world that cannot keep its --speedup says so once, during the mission;
one that keeps it, and a lockstep world, say nothing."""

from __future__ import annotations

import asyncio
import logging
from pathlib import Path

import pytest

from plmarl_sitl.mission import load_mission
from plmarl_sitl.sitl.network.broker import EmbeddedBroker, free_udp_ports
from plmarl_sitl.sitl.pace import Pace
from plmarl_sitl.sitl.world import SitlWorld, WorldConfig

MISSION = Path(__file__).resolve().parents[2] / "missions" / "paper_urban.yaml"


def test_pace_says_it_once_past_the_threshold() -> None:
    pace = Pace(20.0, notice_s=2.0)
    pace.lose(0.1)  # 2 mission s: not more than the threshold
    assert pace.notice(30.0, 2.0) is None
    pace.lose(0.01)
    assert pace.notice(26.0, 4.0) == "running behind --speedup 20 (achieving 6.5x); lower --speedup or use --lockstep"
    pace.lose(10.0)
    assert pace.notice(40.0, 8.0) is None  # once per run


def _fly(speedup: float, episode_s: int, lockstep: bool = False) -> tuple[list[str], SitlWorld]:
    """A world of the paper's mission without agents: it starts the mission after a 1 s
    start timeout with the vehicles on the ground and runs `episode_s` mission seconds."""

    async def main() -> tuple[list[str], SitlWorld]:
        async with EmbeddedBroker() as broker:
            m = load_mission(MISSION)
            world = SitlWorld(WorldConfig(m, broker.url, speedup=speedup, base_port=free_udp_ports(m.n_uavs),
                                          episode_s=episode_s, start_timeout_s=1.0, start_margin_wall_s=0.001,
                                          lockstep=lockstep))
            said: list[str] = []
            world.on_behind = said.append
            async with asyncio.timeout(60):
                await world.run()
            return said, world

    return asyncio.run(main())


@pytest.mark.integration
def test_a_world_that_falls_behind_says_so_once(caplog: pytest.LogCaptureFixture) -> None:
    """1000x is far beyond what one process steps (tens of x here): the mission loses
    hundreds of seconds to the bounded catch-up."""
    with caplog.at_level(logging.WARNING, logger="plmarl.world"):
        said, world = _fly(1000.0, 30)
    assert len(said) == 1 and said[0].startswith("running behind --speedup 1000 (achieving ")
    assert said[0].endswith("x); lower --speedup or use --lockstep")
    assert [r.getMessage() for r in caplog.records if "running behind" in r.getMessage()] == said
    assert world.pacer.pace.lost_s > 2.0


@pytest.mark.integration
@pytest.mark.parametrize("speedup,lockstep", [(2.0, False), (1000.0, True)])
def test_a_world_that_keeps_pace_or_runs_lockstep_says_nothing(speedup: float, lockstep: bool,
                                                                caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.WARNING, logger="plmarl.world"):
        said, world = _fly(speedup, 3, lockstep)
    assert said == [] and not any("running behind" in r.getMessage() for r in caplog.records)
    assert len(world.summary.coverage) == 3  # the mission ran
