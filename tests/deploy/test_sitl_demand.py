"""Integration: the demand map flows from the SITL world over a real broker to real agents,
and every decision of a version-2 policy gets the map the twin would publish at that
instant (the same cells, taken at the same second)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
import torch

from plmarl_sitl.mission import load_mission
from plmarl_sitl.model.demand import is_map_instant, map_period
from plmarl_sitl.twin.env import CoverageEnv

from .conftest import MISSION, run_sitl

pytestmark = [pytest.mark.timeout(150), pytest.mark.integration, pytest.mark.slow]

TUP = 5


def twin_maps(n: int, upto: int) -> dict[int, torch.Tensor]:
    """The twin's published map (nonzero cells) at each of its map instants up to `upto`."""
    m = dataclasses.replace(load_mission(MISSION), n_uavs=n).with_tup(TUP)
    env = CoverageEnv(m, 1, m.seed)
    out = {}
    for t in range(upto + 1):
        if t:
            env.physics_step(torch.zeros(1, n, 3))
        if is_map_instant(t, m.demand.refresh_s, m.timing.decision_every_s):
            d = env.observe().demand[0]
            out[t] = d[d[:, 2] > 0]
    return out


def test_agents_get_the_twins_map_at_the_twins_instants(tmp_path: Path, v2_policy_dir: Path) -> None:
    # On the embedded broker (amqtt), the default; each map rides on its retained copy. Mosquitto carries the
    # same retained maps in every `--broker mosquitto` mission of tests/sitl (one broker here saves CI 45 s).
    n, episode = 3, 64  # maps at t = 0, 30, 60
    run = run_sitl(tmp_path, v2_policy_dir, n=n, broker="amqtt", tup_s=TUP, episode_s=episode, speedup=10.0)
    m = load_mission(MISSION)
    period = map_period(m.demand.refresh_s, m.timing.decision_every_s)
    want = twin_maps(n, episode)
    assert sorted(want) == [0, 30, 60]
    for i in range(n):
        rows = run.trace(i)
        decisions = [r for r in rows if r["decided"]]
        assert len(decisions) >= 15, run.log(i)[-2000:]
        # Every decision used the map of the latest map instant not after it: none a stale one.
        for r in decisions:
            assert r["demand_t"] == r["t"] - r["t"] % period, (i, r["t"], r["demand_t"])
        # ... and that map is the twin's, cell for cell.
        new = {r["t"]: r["demand"] for r in rows if "demand" in r}
        assert sorted(new) == [k for k in want if k <= decisions[-1]["t"]], (i, sorted(new))
        for k, cells in new.items():
            assert torch.equal(torch.tensor(cells), want[k]), (i, k)
        s = run.stats(i)
        assert s is not None and s["rx"]["malformed"] == 0
        assert s["demand"]["accepted"] >= 3 and s["demand"]["late"] == 0 and s["demand"]["stale"] == 0, s["demand"]
