"""Issue 24.3, session 20: moving demand in the training distribution and the CTDE tracking
teacher (learning/train/teacher.py::joint_track, `plmarl train --teacher track --moving-share`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from plmarl_sitl.learning.train.scenarios import ScenarioArgs, describe_distribution, training_mission
from plmarl_sitl.learning.train.teacher import joint_track
from plmarl_sitl.mission import load_mission

ROOT = Path(__file__).resolve().parents[2]
RS, LINK, APART = 100.0, 332.5, 200.0


def _sense(ego: torch.Tensor, centroid: torch.Tensor) -> torch.Tensor:
    """Sensing features with the users' centroid at `centroid` (B, N, 2)."""
    off = (centroid - ego[..., :2]) / RS
    return torch.cat([torch.ones(*ego.shape[:-1], 1), off, torch.full((*ego.shape[:-1], 1), 0.3)], -1)


def test_moving_share_off_keeps_the_old_stream_and_on_draws_walking_crowds() -> None:
    base = load_mission(ROOT / "missions" / "paper_urban.yaml")
    a, b = np.random.default_rng(4), np.random.default_rng(4)
    old = [training_mission(base, a) for _ in range(30)]
    off = [training_mission(base, b, ScenarioArgs(moving_share=0.0)) for _ in range(30)]
    assert old == off  # no extra draw when off: the scenarios of before, one for one
    rng = np.random.default_rng(5)
    on = [training_mission(base, rng, ScenarioArgs(moving_share=1.0)) for _ in range(30)]
    for m in on:
        assert m.users.mobility == "rpgm" and 200.0 <= m.users.rpgm_range_m <= 400.0
        assert 1.5 - 1e-9 <= 0.6 * m.users.max_speed_mps <= 3.0 + 1e-9  # the group's speed
    some = [training_mission(base, rng, ScenarioArgs(moving_share=0.5)).users.mobility for _ in range(200)]
    assert 60 < some.count("rpgm") < 140


def test_the_card_names_moving_demand_only_when_it_is_on() -> None:
    off = describe_distribution(True, (15,), {}, ScenarioArgs())
    assert off == describe_distribution(True, (15,), {}) and "moving_share" not in off and "moving" not in off
    on = describe_distribution(True, (15,), {}, ScenarioArgs(moving_share=0.4))
    assert on["moving_share"] == 0.4 and on["moving_speed_mps"] == [1.5, 3.0] and "moving" in on


def test_the_joint_teacher_follows_the_crowd_as_far_as_the_team_stays_linked() -> None:
    """Two UAVs 290 m apart (link 332.5 m): each crowd walks 30 m away from the other. The first
    (longest step) takes 30 m, the second only what keeps the pair within the link (a quarter of
    its step is the largest fraction that does). A third UAV, out of their range, senses nothing and stays."""
    plan = torch.tensor([[[0.0, 0.0], [0.0, 290.0], [1000.0, 1000.0]]], dtype=torch.float64)
    ego = torch.cat([plan, torch.zeros(1, 3, 1)], -1)
    sense = _sense(ego, plan + torch.tensor([[[0.0, -31.0], [0.0, 30.0], [0.0, 0.0]]], dtype=torch.float64))
    sense[0, 2] = 0.0
    alive = torch.ones(1, 3, dtype=torch.bool)
    out = joint_track(plan, ego, sense, alive, radius_m=RS, leash_m=30.0, link_m=LINK, apart_m=APART)
    assert torch.allclose(out[0, 0], torch.tensor([0.0, -30.0], dtype=torch.float64))
    assert torch.allclose(out[0, 1], torch.tensor([0.0, 290.0 + 0.25 * 30.0], dtype=torch.float64))
    assert torch.equal(out[0, 2], plan[0, 2])
    # alone, nothing bounds it but the leash; a dead UAV's point is the plan's
    alive[0, 1] = alive[0, 2] = False
    lone = joint_track(plan, ego, sense, alive, radius_m=RS, leash_m=30.0, link_m=LINK, apart_m=APART)
    assert torch.allclose(lone[0, 0], torch.tensor([0.0, -30.0], dtype=torch.float64)) and torch.equal(lone[0, 1], plan[0, 1])


def test_the_joint_teacher_keeps_two_uavs_off_one_crowd() -> None:
    """Two points 210 m apart, both crowds between them: neither may come closer than 2 R_s."""
    plan = torch.tensor([[[0.0, 0.0], [0.0, 210.0]]], dtype=torch.float64)
    ego = torch.cat([plan, torch.zeros(1, 2, 1)], -1)
    sense = _sense(ego, torch.tensor([[[0.0, 105.0], [0.0, 105.0]]], dtype=torch.float64))
    out = joint_track(plan, ego, sense, torch.ones(1, 2, dtype=torch.bool), radius_m=RS, leash_m=30.0, link_m=LINK,
                      apart_m=APART)
    assert float(torch.linalg.norm(out[0, 0] - out[0, 1])) >= APART - 1e-6
    assert not torch.equal(out, plan)  # a fraction that keeps the spacing is taken


@pytest.mark.parametrize("argv, said", [
    (["--moving-share", "1.5"], "--moving-share 1.5: must be in [0, 1]"),
    (["--moving-share", "0.5", "--scenarios", "mission"], "--moving-share needs --scenarios general"),
    (["--teacher-track-m", "0"], "--teacher-track-m 0: must be > 0"),
    (["--teacher-track-link", "1.2"], "--teacher-track-link 1.2: must be in (0, 1]"),
])
def test_bad_moving_options_are_one_line(tmp_path: Path, monkeypatch, capsys, argv: list[str], said: str) -> None:
    from plmarl_sitl.cli import main

    monkeypatch.chdir(tmp_path)
    assert main(["train", "--out", "x", "--episodes", "1", *argv]) == 2
    err = capsys.readouterr().err
    assert said in err and "Traceback" not in err


def test_imitation_with_the_track_teacher_on_moving_demand_runs() -> None:
    from plmarl_sitl.learning.nn import Actor, BeliefTracker, make_predictor
    from plmarl_sitl.learning.train.imitation import ImitationArgs, imitate_oracle

    mission = load_mission(ROOT / "missions" / "paper_urban.yaml")
    torch.manual_seed(0)
    tracker = BeliefTracker(make_predictor("hold"), 10, 1.0)
    args = ImitationArgs(rounds=1, episodes_per_round=2, epochs=1, tup_choices=(15,), seed=1, teacher="track",
                         moving_share=1.0)
    res = imitate_oracle(Actor(), tracker, mission, args, log=lambda s: None)
    assert res["episodes"] == 2 and res["final_mse"] == res["final_mse"] and res["args"]["teacher"] == "track"


def test_a_link_margin_holds_linked_pairs_closer_and_never_looser() -> None:
    """margin 250 m: the pair 290 m apart in the plan may not grow at all (max(250, 290) = 290), and
    the margin never lets a point go where the plain check would not."""
    plan = torch.tensor([[[0.0, 0.0], [0.0, 290.0], [1000.0, 1000.0]]], dtype=torch.float64)
    ego = torch.cat([plan, torch.zeros(1, 3, 1)], -1)
    sense = _sense(ego, plan + torch.tensor([[[0.0, -31.0], [0.0, 30.0], [0.0, 0.0]]], dtype=torch.float64))
    sense[0, 2] = 0.0
    alive = torch.ones(1, 3, dtype=torch.bool)
    tight = joint_track(plan, ego, sense, alive, radius_m=RS, leash_m=30.0, link_m=LINK, apart_m=APART, margin_m=250.0)
    assert torch.equal(tight[0, :2], plan[0, :2])
    # pulled together they may move (the pair gets shorter)
    sense = _sense(ego, plan + torch.tensor([[[0.0, 30.0], [0.0, -30.0], [0.0, 0.0]]], dtype=torch.float64))
    sense[0, 2] = 0.0
    closer = joint_track(plan, ego, sense, alive, radius_m=RS, leash_m=30.0, link_m=LINK, apart_m=APART, margin_m=250.0)
    assert float(torch.linalg.norm(closer[0, 0] - closer[0, 1])) < 290.0
