"""The world's sensing and coverage in one numpy pass give the users the twin's torch code gives."""

import torch

from plmarl_sitl.model.coverage import covered_users
from plmarl_sitl.sitl.ground import covered_np, sensed_users


def _per_vehicle_torch(users: torch.Tensor, pos: torch.Tensor, alive: torch.Tensor, radius_m: float) -> list:
    """The rule as the world applied it before (and the twin applies it): one vehicle at a time."""
    out = []
    for i in range(pos.shape[0]):
        if not bool(alive[i]):
            out.append(None)
            continue
        d = users - pos[i, :2]
        out.append(users[(d * d).sum(-1) <= radius_m**2].tolist())
    return out


def test_sensed_users_match_the_per_vehicle_rule_bit_for_bit():
    g = torch.Generator().manual_seed(7)
    edge_cases = 0
    for trial in range(200):
        n_users = int(torch.randint(0, 2000, (1,), generator=g))
        n = int(torch.randint(1, 30, (1,), generator=g))
        users = (torch.rand(n_users, 2, generator=g, dtype=torch.float64) * 3000).float()
        xy = torch.rand(n, 2, generator=g, dtype=torch.float64) * 3000
        pos = torch.cat([xy, -torch.rand(n, 1, generator=g, dtype=torch.float64) * 120], 1).float()
        radius = (150.0, 200.0, 123.4)[trial % 3]
        if n_users and trial % 2 == 0:  # a user on the sensing circle, where rounding decides
            pos[0, :2] = users[0] + torch.tensor([radius, 0.0])
            edge_cases += 1
        alive = torch.rand(n, generator=g) > 0.2
        assert sensed_users(users, pos, alive, radius) == _per_vehicle_torch(users, pos, alive, radius), trial
    assert edge_cases > 50


def test_no_users_and_dead_vehicles():
    users = torch.zeros(0, 2)
    pos = torch.tensor([[0.0, 0.0, -50.0], [10.0, 0.0, -50.0]])
    assert sensed_users(users, pos, torch.tensor([True, False]), 150.0) == [[], None]


def test_covered_np_matches_the_twins_covered_users_bit_for_bit():
    g = torch.Generator().manual_seed(11)
    edge_cases = 0
    for trial in range(300):
        n_users = int(torch.randint(0, 2000, (1,), generator=g))
        n = int(torch.randint(1, 30, (1,), generator=g))
        users = (torch.rand(1, n_users, 2, generator=g, dtype=torch.float64) * 3000).float()[0]  # a view, as UserState.xy[0]
        xy = torch.rand(n, 2, generator=g, dtype=torch.float64) * 3000
        pos = torch.cat([xy, -torch.rand(n, 1, generator=g, dtype=torch.float64) * 120], 1).float()
        radius = (torch.rand(n, generator=g, dtype=torch.float64) * 300).float()
        if n_users and trial % 2 == 0:  # a user on a coverage circle, where rounding decides
            pos[0, :2] = users[0] + torch.stack([radius[0], torch.tensor(0.0)])
            edge_cases += 1
        alive = torch.rand(n, generator=g) > 0.2
        want = covered_users(users, pos, alive, radius)
        got = torch.from_numpy(covered_np(users, pos, alive, radius))
        assert torch.equal(got, want), trial
        assert float(got.float().mean()) == float(want.float().mean()) or n_users == 0
    assert edge_cases > 50
