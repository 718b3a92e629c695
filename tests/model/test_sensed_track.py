"""The plan point moved toward the sensed users (model/sensed_track.py, issue 24.3)."""

import pytest
import torch

from plmarl_sitl.config import ConfigError
from plmarl_sitl.mission import load_mission, mission_from_dict
from plmarl_sitl.model.coverage import sensing_features
from plmarl_sitl.model.sensed_track import (
    SlackCache,
    mission_toward_sensed,
    plan_slack,
    spacing_slack,
    toward_sensed,
    tree_slack,
)

MISSION = load_mission("missions/paper_urban.yaml")


def _sense(ego_xy, users):
    pos = torch.tensor([[ego_xy[0], ego_xy[1], -80.0]])
    return sensing_features(pos, torch.tensor(users, dtype=torch.float32), 100.0, 60)[0]


def test_moves_toward_the_centroid_at_most_the_bound():
    target = torch.tensor([500.0, 500.0])
    sense = _sense((500.0, 500.0), [[560.0, 500.0], [580.0, 500.0]])  # centroid 70 m north
    near = toward_sensed(target, torch.tensor([500.0, 500.0]), sense, 100.0, 100.0)
    assert torch.allclose(near, torch.tensor([570.0, 500.0]), atol=1e-3)  # within the bound: onto the centroid
    capped = toward_sensed(target, torch.tensor([500.0, 500.0]), sense, 100.0, 30.0)
    assert torch.allclose(capped, torch.tensor([530.0, 500.0]), atol=1e-3)


def test_the_shift_is_from_the_plan_point_not_from_the_uav():
    """The UAV 40 m east of its point, its users' centroid 30 m north of it: the point moves
    toward the centroid, and never more than the bound from the plan point."""
    target = torch.tensor([500.0, 500.0])
    ego = torch.tensor([500.0, 540.0])
    sense = _sense((500.0, 540.0), [[530.0, 540.0]])
    out = toward_sensed(target, ego, sense, 100.0, 20.0)
    assert float(torch.linalg.vector_norm(out - target)) == pytest.approx(20.0, abs=1e-3)
    assert float(out[0]) > 500.0 and float(out[1]) > 500.0


def test_nothing_sensed_or_off_keeps_the_plan_point():
    target = torch.tensor([[500.0, 500.0], [100.0, 100.0]])
    ego = torch.tensor([[500.0, 500.0], [100.0, 100.0]])
    sense = torch.stack([_sense((500.0, 500.0), [[560.0, 500.0]]), _sense((100.0, 100.0), [[900.0, 900.0]])])
    out = toward_sensed(target, ego, sense, 100.0, 30.0)
    assert not torch.equal(out[0], target[0]) and torch.equal(out[1], target[1])  # the second senses no one
    assert torch.equal(toward_sensed(target, ego, sense, 100.0, 0.0), target)
    assert torch.equal(mission_toward_sensed(MISSION, target, ego, sense), target)  # the default: off

    def no_copy() -> tuple[torch.Tensor, torch.Tensor]:
        raise AssertionError("the plan's points were copied with the shift off")

    assert torch.equal(mission_toward_sensed(MISSION, target, ego, sense, no_copy), target)  # off: no copy asked for


def test_mission_option_is_validated():
    assert MISSION.track_sensed_m == 0.0
    assert MISSION.with_track_sensed(30).track_sensed_m == 30.0
    with pytest.raises(ConfigError, match="track_sensed_m"):
        mission_from_dict({"name": "x", "track_sensed_m": -5.0})


def _mst_slack_by_hand(pts, dead, link_m):
    """Kruskal on the live points (a different algorithm from the module's Prim)."""
    live = [i for i in range(len(pts)) if not dead[i]]
    edges = sorted((float(torch.linalg.vector_norm(pts[i] - pts[j])), i, j) for a, i in enumerate(live) for j in live[a + 1:])
    root = {i: i for i in live}

    def find(i):
        while root[i] != i:
            i = root[i]
        return i

    out = [float("inf")] * len(pts)
    for d, i, j in edges:
        if find(i) != find(j):
            root[find(i)] = find(j)
            half = max(0.0, (link_m - d) / 2)
            out[i], out[j] = min(out[i], half), min(out[j], half)
    return out


def test_tree_slack_is_half_the_spare_length_of_each_spanning_tree_edge():
    gen = torch.Generator().manual_seed(3)
    for _ in range(50):
        n = int(torch.randint(1, 9, (1,), generator=gen))
        pts = torch.rand(n, 2, generator=gen, dtype=torch.float64) * 600
        dead = (torch.rand(n, generator=gen) < 0.2).tolist()
        held = pts.clone()
        held[torch.tensor(dead, dtype=torch.bool)] = float("nan")
        got = tree_slack(held, 332.5).tolist()
        want = _mst_slack_by_hand(pts, dead, 332.5)
        assert got == pytest.approx(want), (got, want)
    batch = torch.rand(3, 4, 5, 2, generator=gen, dtype=torch.float64) * 600  # batched = one copy at a time
    out = tree_slack(batch, 332.5)
    assert all(torch.equal(out[i, j], tree_slack(batch[i, j], 332.5)) for i in range(3) for j in range(4))


def test_the_plan_tree_bounds_the_shift():
    """Points 300 m apart (32.5 m of spare link length): each may move 16.25 m, not 30."""
    m = MISSION.with_track_sensed(30.0)
    points = torch.tensor([[500.0, 500.0], [800.0, 500.0]], dtype=torch.float64)
    sense = _sense((500.0, 500.0), [[450.0, 500.0]])  # users 50 m south of UAV 0
    out = mission_toward_sensed(m, torch.tensor([500.0, 500.0]), torch.tensor([500.0, 500.0, -80.0]), sense,
                                lambda: (points, torch.tensor(0)))
    assert float(out[0]) == pytest.approx(500.0 - (0.95 * 350.0 - 300.0) / 2, abs=1e-3)
    free = mission_toward_sensed(m, torch.tensor([500.0, 500.0]), torch.tensor([500.0, 500.0, -80.0]), sense)
    assert float(free[0]) == pytest.approx(470.0, abs=1e-3)  # without the plan's points: the 30 m bound alone


def test_slack_cache_recomputes_when_the_points_change():
    cache = SlackCache()
    a = torch.tensor([[0.0, 0.0], [300.0, 0.0], [float("nan"), float("nan")]], dtype=torch.float64)
    b = torch.tensor([[0.0, 0.0], [200.0, 0.0], [float("nan"), float("nan")]], dtype=torch.float64)
    for pts in (a, a, b, a, b):
        assert torch.equal(cache(pts, 332.5, 200.0), plan_slack(pts, 332.5, 200.0))


def test_points_close_in_the_plan_do_not_converge():
    """Two plan points 100 m apart on one crowd (R_s 100 m: closer than 2 R_s) keep their places;
    points 260 m apart may each close in by 30 m, the pair then 200 m apart, not less."""
    nan = float("nan")
    pts = torch.tensor([[0.0, 0.0], [100.0, 0.0], [nan, nan]], dtype=torch.float64)
    assert spacing_slack(pts, 200.0).tolist()[:2] == [0.0, 0.0]
    far = torch.tensor([[0.0, 0.0], [260.0, 0.0]], dtype=torch.float64)
    assert spacing_slack(far, 200.0).tolist() == pytest.approx([30.0, 30.0])
    m = MISSION.with_track_sensed(30.0)
    sense = _sense((0.0, 0.0), [[50.0, 0.0]])  # UAV 0 senses the crowd between the two
    out = mission_toward_sensed(m, torch.tensor([0.0, 0.0]), torch.tensor([0.0, 0.0, -80.0]), sense, lambda: (pts[:2], torch.tensor(0)))
    assert out.tolist() == [0.0, 0.0]
