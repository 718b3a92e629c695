"""The plan point moved toward the sensed users (model/sensed_track.py, issue 24.3)."""

import pytest
import torch

from plmarl_sitl.config import ConfigError
from plmarl_sitl.mission import load_mission, mission_from_dict
from plmarl_sitl.model.coverage import sensing_features
from plmarl_sitl.model.sensed_track import mission_toward_sensed, toward_sensed

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


def test_mission_option_is_validated():
    assert MISSION.track_sensed_m == 0.0
    assert MISSION.with_track_sensed(30).track_sensed_m == 30.0
    with pytest.raises(ConfigError, match="track_sensed_m"):
        mission_from_dict({"name": "x", "track_sensed_m": -5.0})
