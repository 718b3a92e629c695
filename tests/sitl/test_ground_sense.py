"""The world's sensing in one numpy pass gives the users the twin's per-vehicle torch test gives."""

import torch

from plmarl_sitl.sitl.ground import sensed_users


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
