"""Channel (Al-Hourani) and the coverage definition on hand-built geometries."""

import math

import torch

from plmarl_sitl.mission import Channel
from plmarl_sitl.model.channel import CoverageRadius, a2g_path_loss_db, coverage_radius, fspl_db, los_probability
from plmarl_sitl.model.coverage import coverage_rate, covered_users, sensing_features

CH = Channel()


def test_los_probability_rises_with_elevation():
    elev = torch.linspace(0.0, 90.0, 181, dtype=torch.float64)
    p = los_probability(elev, CH.los_a, CH.los_b)
    assert bool((p[1:] > p[:-1]).all())


def test_los_probability_textbook_values():
    p = lambda deg: float(los_probability(torch.tensor(deg, dtype=torch.float64), 9.61, 0.16))  # noqa: E731
    assert math.isclose(p(9.61), 1 / (1 + 9.61), rel_tol=1e-12)  # theta = a
    assert math.isclose(p(45.0), 1 / (1 + 9.61 * math.exp(-0.16 * (45 - 9.61))), rel_tol=1e-12)
    assert p(45.0) > 0.96 and p(90.0) > 0.9999 and math.isclose(p(0.0), 1 / (1 + 9.61 * math.exp(0.16 * 9.61)), rel_tol=1e-12)


def test_fspl_at_one_km_two_ghz():
    # 20 log10(1000) + 20 log10(2e9) - 147.55 = 98.47 dB
    assert abs(float(fspl_db(torch.tensor(1000.0), 2e9)) - 98.47) < 0.01


def test_path_loss_grows_with_ground_distance_at_fixed_altitude():
    r = torch.linspace(0.0, 500.0, 501, dtype=torch.float64)
    pl = a2g_path_loss_db(r, torch.full_like(r, 100.0), CH)
    assert bool((pl[1:] > pl[:-1]).all())


def test_coverage_radius_table_matches_the_path_loss_threshold():
    cr = CoverageRadius(CH, 100.0, 40.0, 150.0)
    for h in (45.0, 60.0, 140.0):
        r = float(cr(torch.tensor(h, dtype=torch.float64)))
        assert 0 < r < 100.0
        pl = float(a2g_path_loss_db(torch.tensor(r, dtype=torch.float64), torch.tensor(h, dtype=torch.float64), CH))
        assert abs(pl - CH.max_path_loss_db) < 0.05
    alt, best = cr.best_altitude()
    assert best == 100.0 and 70.0 < alt < 125.0


def _uav(n, e, alt):
    return torch.tensor([[n, e, -alt]])


def test_coverage_hand_built():
    users = torch.tensor([[0.0, 99.0], [0.0, 101.0], [300.0, 0.0], [300.0, 50.0]])
    uavs = torch.cat([_uav(0.0, 0.0, 100.0), _uav(300.0, 0.0, 100.0)])
    alive = torch.tensor([True, True])
    radius = torch.tensor([100.0, 100.0])
    assert covered_users(users, uavs, alive, radius).tolist() == [True, False, True, True]
    assert float(coverage_rate(users, uavs, alive, radius)) == 0.75
    # A dead UAV covers nobody; a smaller radius covers less.
    assert covered_users(users, uavs, torch.tensor([True, False]), radius).tolist() == [True, False, False, False]
    assert covered_users(users, uavs, alive, torch.tensor([100.0, 40.0])).tolist() == [True, False, True, False]


def test_sensing_features_hand_built():
    users = torch.tensor([[10.0, 0.0], [-10.0, 0.0], [0.0, 30.0], [500.0, 500.0]])
    f = sensing_features(_uav(0.0, 0.0, 80.0), users, sensing_m=100.0, cluster_size=60)
    count, mn, me, rms = f[0].tolist()
    assert math.isclose(count, 3 / 60, rel_tol=1e-6)
    assert abs(mn) < 1e-7 and math.isclose(me, 10.0 / 100.0, rel_tol=1e-6)
    assert math.isclose(rms, math.sqrt((100 + 100 + 900) / 3) / 100.0, rel_tol=1e-6)
    none = sensing_features(_uav(900.0, 900.0, 80.0), users[:3], 100.0, 60)
    assert none.abs().sum() == 0


def test_coverage_radius_is_tabulated_once_per_constants_and_equals_a_fresh_table():
    shared = coverage_radius(CH, 300.0, 30.0, 200.0)
    assert coverage_radius(CH, 300.0, 30.0, 200.0) is shared
    fresh = CoverageRadius(CH, 300.0, 30.0, 200.0)
    assert torch.equal(shared.table, fresh.table) and shared.best_altitude() == fresh.best_altitude()
    other = coverage_radius(Channel(max_path_loss_db=CH.max_path_loss_db - 3.0), 300.0, 30.0, 200.0)
    assert other is not shared and float(other.table.max()) < float(shared.table.max())
