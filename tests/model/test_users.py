"""Ground users: speed bound, boundary reflection, cluster layouts."""

import dataclasses

import pytest
import torch

from plmarl_sitl.config import ConfigError
from plmarl_sitl.mission import Area, Users, load_mission, mission_from_dict
from plmarl_sitl.model.users import MOBILITY_KINDS, cluster_centres, init_users, step_users

MISSION = load_mission("missions/paper_urban.yaml")


@pytest.mark.parametrize("mobility", [*MOBILITY_KINDS, "mixed"])
def test_speed_bound_and_area_hold(mobility):
    m = dataclasses.replace(MISSION, users=dataclasses.replace(MISSION.users, mobility=mobility))
    gen = torch.Generator().manual_seed(1)
    s = init_users(m, 8, gen)
    for _ in range(300):
        prev = s.pos.clone()
        s = step_users(s, m, 1.0, gen)
        step = torch.linalg.vector_norm(s.pos - prev, dim=1)
        # Reflection can only shorten the displacement (float32 positions near 1 km: ulp 6e-5 m).
        assert float(step.max()) <= m.users.max_speed_mps + 2e-4
        assert float(torch.linalg.vector_norm(s.vel, dim=1).max()) <= m.users.max_speed_mps * (1 + 1e-6)
        assert float(s.pos.min()) >= 0.0
        assert float(s.pos[:, 0].max()) <= m.area.north_m and float(s.pos[:, 1].max()) <= m.area.east_m


def test_users_reflect_off_the_edge():
    # Tiny area: users constantly hit the walls.
    users = dataclasses.replace(MISSION.users, layout="lattice", cluster_centers=(), cluster_spacing_m=10.0, cluster_std_m=20.0, gm_alpha=1.0)
    m = dataclasses.replace(MISSION, area=Area(north_m=100.0, east_m=100.0), users=users)
    gen = torch.Generator().manual_seed(2)
    s = init_users(m, 4, gen)
    for _ in range(500):
        s = step_users(s, m, 1.0, gen)
        assert 0.0 <= float(s.pos.min()) and float(s.pos.max()) <= 100.0


def test_fixed_layout_uses_the_mission_centres():
    c = cluster_centres(MISSION, 3, torch.Generator().manual_seed(0))
    assert c.shape == (3, 4, 2)
    assert torch.allclose(c[0], torch.tensor(MISSION.users.cluster_centers, dtype=c.dtype))


@pytest.mark.parametrize("clusters", [4, 12, 20])
def test_random_layout_is_connected_and_spread(clusters):
    # 20 clusters in 1 km^2 jam the sequential draw; they are grown on a lattice instead.
    users = Users(count=60 * clusters, layout="random")
    m = dataclasses.replace(MISSION, users=users)
    c = cluster_centres(m, 20, torch.Generator().manual_seed(0))
    assert c.shape == (20, clusters, 2)
    d = torch.cdist(c, c)
    eye = torch.eye(clusters, dtype=torch.bool)
    assert float(d[:, ~eye].min()) >= 2 * m.radii.sensing_m - 1e-6
    assert float(c.min()) >= m.users.cluster_std_m - 1e-6
    assert float(c.max()) <= m.area.north_m - m.users.cluster_std_m + 1e-6
    # Connected under 0.8 R_comm: every centre has a chain to the others.
    adj = (d <= 0.8 * m.radii.comm_m + 1e-6) & ~eye
    reach = adj.clone() | eye
    for _ in range(clusters):
        reach = reach | (reach.double() @ reach.double() > 0)
    assert bool(reach.all())
    # Each layout of the batch is its own.
    assert float((c[0] - c[1]).abs().max()) > 1.0


@pytest.mark.parametrize(
    ("change", "says"),
    [
        ({"users": Users(count=60 * 40, layout="random")}, "40 clusters 2 R_s apart do not fit"),
        ({"radii": dataclasses.replace(MISSION.radii, sensing_m=150.0)}, "radii.sensing_m 150 is too large"),
    ],
)
def test_random_layout_that_cannot_exist_is_a_config_error(change, says):
    users = change.get("users", Users(layout="random"))
    m = dataclasses.replace(MISSION, **{**change, "users": users})
    with pytest.raises(ConfigError, match=says) as err:
        cluster_centres(m, 2, torch.Generator().manual_seed(0))
    assert err.value.path == "users.layout"


def _rpgm(range_m: float, speed: float = 0.5) -> object:
    return dataclasses.replace(MISSION, users=dataclasses.replace(MISSION.users, mobility="rpgm", max_speed_mps=speed,
                                                                  rpgm_range_m=range_m))


def test_rpgm_range_unset_is_the_two_cluster_std_walk_bit_for_bit():
    """rpgm_range_m 0 (the default) and 2 cluster_std_m draw the same walks: existing missions keep their users."""
    runs = []
    for m in (_rpgm(0.0), _rpgm(2 * MISSION.users.cluster_std_m)):
        gen = torch.Generator().manual_seed(5)
        s = init_users(m, 4, gen)
        for _ in range(200):
            s = step_users(s, m, 1.0, gen)
        runs.append(s.pos)
    # the explicit range clamps waypoints into the area; none of the paper map's reach the edge
    assert torch.equal(runs[0], runs[1])


def test_rpgm_wide_range_walks_groups_far_from_home_inside_the_area():
    """A wide, fast RPGM (the moving-demand missions): group reference points leave the 70 m of
    the default walk and every waypoint stays in the area."""
    far = []
    for range_m in (0.0, 400.0):
        m = _rpgm(range_m, speed=4.0)
        gen = torch.Generator().manual_seed(6)
        s = init_users(m, 4, gen)
        dist = torch.zeros(())
        for _ in range(400):
            s = step_users(s, m, 1.0, gen)
            dist = torch.maximum(dist, torch.linalg.vector_norm(s.group_ref - s.home, dim=1).max())
            assert float(s.group_wp.min()) >= 0.0 and float(s.group_wp.max()) <= 1000.0
        far.append(float(dist))
    assert far[0] <= 2 * MISSION.users.cluster_std_m + 1e-3
    assert far[1] > 200.0, far


def test_rpgm_range_must_not_be_negative():
    with pytest.raises(ConfigError, match="rpgm_range_m"):
        mission_from_dict({"name": "x", "users": {"mobility": "rpgm", "rpgm_range_m": -1.0}})
