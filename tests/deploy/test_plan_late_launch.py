"""The agent's team plan when the first instant's states arrive after the first decision
(deploy/agent/plan.py): seen in SITL on a loaded machine, where the bounded first wait
ended before any neighbour's state of t = 0 was in."""

from __future__ import annotations

import math

import torch

from plmarl_sitl.deploy.agent.plan import AgentPlan
from plmarl_sitl.model.demand import cell_centres, demand_cells, demand_map
from plmarl_sitl.model.users import init_users

NEVER = math.inf


def _launch(mission) -> torch.Tensor:  # noqa: ANN001
    n, ln = mission.n_uavs, mission.launch
    east = ln.east_m + ln.spacing_m * (torch.arange(n, dtype=torch.float32) - (n - 1) / 2)
    return torch.stack([torch.full((n,), float(ln.north_m)), east, torch.full((n,), -60.0),
                        torch.zeros(n), torch.zeros(n), torch.zeros(n)], -1)


def _map(mission) -> tuple[float, torch.Tensor]:  # noqa: ANN001
    users = init_users(mission, 1, torch.Generator().manual_seed(1))
    a = mission.area
    counts = demand_map(users.xy[0], a.north_m, a.east_m, mission.demand.cell_m)
    return 0.0, demand_cells(counts, cell_centres(a.north_m, a.east_m, mission.demand.cell_m))


def test_first_instant_states_that_arrive_late_give_the_plan_of_an_agent_that_heard_them_at_once(mission) -> None:
    n = mission.n_uavs
    held = _launch(mission)
    demand = _map(mission)
    on_time = [AgentPlan(mission, i) for i in range(n)]
    late = [AgentPlan(mission, i) for i in range(n)]
    want = []
    for i in range(n):
        t_rx = torch.zeros(n)
        want.append(on_time[i].target(0, held[i], held, t_rx, demand))
    assert len({tuple(t.tolist()) for t in want}) == n  # one point per UAV
    for i in range(n):
        nobody = torch.full((n,), NEVER)
        alone = late[i].target(0, held[i], held, nobody, demand)  # decided before any state of t = 0 was in
        got = late[i].target(3, held[i], held, torch.zeros(n), demand)  # they arrived at t = 1..2
        assert torch.equal(got, want[i]), (i, alone, got, want[i])
    # Once the plan follows a newer map it is not restarted.
    again = AgentPlan(mission, 0)
    again.target(0, held[0], held, torch.full((n,), NEVER), demand)
    again.target(30, held[0], held, torch.full((n,), NEVER), (30.0, demand[1]))
    assert again.first_counts is None
