"""The neighbourhood plan (`coordination: local`, model/local_plan.py): the twin and the
deployed agent compute the same points; agents that know the same agree; an agent's cost
per map does not grow with N or the area (issue 24, part 2)."""

from __future__ import annotations

import dataclasses
import statistics
import time

import numpy as np
import pytest
import torch

from plmarl_sitl.config import PAPER_MISSION, ConfigError
from plmarl_sitl.deploy.agent.coordination import agent_plan
from plmarl_sitl.deploy.agent.local_plan import LocalAgentPlan
from plmarl_sitl.deploy.agent.plan import AgentPlan
from plmarl_sitl.learning.eval.controllers import ServiceController
from plmarl_sitl.learning.nn.local_targets import LocalTargets, local_plan_of
from plmarl_sitl.learning.nn.plan import ServiceTargets
from plmarl_sitl.mission import load_mission, mission_from_dict
from plmarl_sitl.model.demand import map_period
from plmarl_sitl.twin.env import CoverageEnv


def _local(path=PAPER_MISSION, **kw):  # noqa: ANN001, ANN003, ANN202
    m = load_mission(path).with_coordination("local")
    return dataclasses.replace(m, **kw) if kw else m


def test_the_mission_chooses_the_coordination() -> None:
    team = load_mission(PAPER_MISSION)
    assert team.coordination == "team"
    assert isinstance(ServiceTargets.of(team), ServiceTargets) and isinstance(agent_plan(team, 0), AgentPlan)
    local = team.with_coordination("local")
    assert isinstance(ServiceTargets.of(local), LocalTargets) and isinstance(agent_plan(local, 0), LocalAgentPlan)
    with pytest.raises(ConfigError):
        mission_from_dict({"name": "x", "coordination": "global"})


@pytest.mark.parametrize(("path", "seed"), [(PAPER_MISSION, 5), ("missions/suite/n12.yaml", 6), ("missions/suite/failure_2of6_a.yaml", 8)])
def test_twin_and_agent_compute_the_same_points(path: str, seed: int) -> None:
    """A twin episode flown by the plan follower on the local plan; at every decision each
    agent's `LocalAgentPlan`, fed that agent's own view (its state, its neighbour table and
    N_i, the map's nonzero cells as the wire carries them), gives the twin's point bit for bit."""
    m = _local(path)
    env = CoverageEnv(m, 1, seed)
    ctl = ServiceController(m)
    ctl.reset()
    obs = env.reset()
    period = map_period(m.demand.refresh_s, m.timing.decision_every_s)
    agents = [LocalAgentPlan(m, i) for i in range(m.n_uavs)]
    solved = 0
    while obs.t < m.timing.episode_s:
        act = ctl.act(obs)
        twin = ctl.targets.last[0]
        cells = obs.demand[0][obs.demand[0][:, 2] > 0]
        for i, ag in enumerate(agents):
            if not bool(obs.alive[0, i]):
                continue
            got = ag.target(obs.t, obs.ego[0, i], obs.nbr_state[0, i], obs.nbr_t_rx[0, i],
                            (float(obs.t - obs.t % period), cells), obs.nbr_mask[0, i])
            assert torch.equal(got, twin[i]), (obs.t, i, got, twin[i])
        solved += obs.t % period == 0
        obs, _, _ = env.step(act)
    assert solved >= 6


def test_agents_that_know_the_same_agree() -> None:
    """The paper's launch, everyone heard: the four agents' points are four distinct points."""
    m = _local()
    env = CoverageEnv(m, 1, 3)
    obs = env.reset()
    full = torch.ones(m.n_uavs, dtype=torch.bool)
    cells = obs.demand[0][obs.demand[0][:, 2] > 0]
    pts = []
    for i in range(m.n_uavs):
        mask = full.clone()
        mask[i] = False
        t_rx = torch.zeros(m.n_uavs)
        pts.append(LocalAgentPlan(m, i).target(0, obs.ego[0, i], obs.ego[0], t_rx, (0.0, cells), mask).numpy())
    pts = np.stack(pts)
    d = np.sqrt(((pts[:, None] - pts[None]) ** 2).sum(-1)) + np.eye(m.n_uavs) * 1e9
    assert d.min() >= 2 * m.radii.safe_m


def _scale(n: int, side: float):  # noqa: ANN202
    """A mission of n UAVs over side x side with the scale_100 lattice, and a twin instant."""
    m = load_mission("missions/scale_100.yaml").with_coordination("local")
    m = dataclasses.replace(m, n_uavs=n, area=dataclasses.replace(m.area, north_m=side, east_m=side),
                            users=dataclasses.replace(m.users, count=60 * n),
                            launch=dataclasses.replace(m.launch, north_m=side / 2, east_m=side / 2))
    obs = CoverageEnv(m, 1, 0).reset()
    return m, obs


def test_cost_per_map_does_not_grow_with_the_area() -> None:
    """CPU per new map of one agent (set_map + solve) at the launch: the same N over 1 km and
    3 km within 2x (the window is at most 3 x 3 tiles whatever the area), and N = 100 over
    3 km, where the launch line puts ~80 teammates in the window (the densest team an agent
    has: its cost is O(teammates in its window), not O(N)), below 20 ms."""
    cost = {}
    for n, side in [(4, 1000.0), (4, 3000.0), (100, 3000.0)]:
        m, obs = _scale(n, side)
        plan = local_plan_of(m)
        i0, i1, j0, j1 = plan.window(np.array([side / 2, side / 2]))
        assert (i1 - i0) * (j1 - j0) <= (3 * plan.reach) ** 2
        cells = obs.demand[0][obs.demand[0][:, 2] > 0].double().numpy()
        me = n // 2
        mask = np.ones(n, dtype=bool)
        mask[me] = False
        rx = np.zeros(n)
        rx[me] = -1.0
        held = obs.ego[0].double().numpy()
        times = []
        for _ in range(15):
            t0 = time.thread_time()
            plan.set_map(cells)
            plan.solve(me, plan.team(me, held[me, :2], held, rx, mask, 0.0, {}), {})
            times.append(time.thread_time() - t0)
        cost[(n, side)] = statistics.median(times)
    assert cost[(4, 3000.0)] < 2.0 * cost[(4, 1000.0)] + 0.001, cost
    assert cost[(100, 3000.0)] < 0.020, cost
