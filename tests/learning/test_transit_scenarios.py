"""Issue 24.3, session 21: long transits in the training distribution (`plmarl train --transit-share`,
learning/train/scenarios.py::_transit): a strip, a chain of clusters along it, a launch near one end."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from plmarl_sitl.learning.train.scenarios import ScenarioArgs, describe_distribution, random_launch, training_mission
from plmarl_sitl.mission import load_mission
from plmarl_sitl.twin.env import CoverageEnv

ROOT = Path(__file__).resolve().parents[2]


def test_transit_share_off_keeps_the_old_stream() -> None:
    base = load_mission(ROOT / "missions" / "paper_urban.yaml")
    a, b = np.random.default_rng(4), np.random.default_rng(4)
    old = [training_mission(base, a, ScenarioArgs(moving_share=0.5)) for _ in range(30)]
    off = [training_mission(base, b, ScenarioArgs(moving_share=0.5, transit_share=0.0)) for _ in range(30)]
    assert old == off  # no extra draw when off: the scenarios of before, one for one
    assert all(random_launch(m, True) for m in off)


def test_a_transit_is_a_strip_launched_far_short_of_a_chain_of_clusters() -> None:
    base = load_mission(ROOT / "missions" / "paper_urban.yaml")
    rng = np.random.default_rng(5)
    args = ScenarioArgs(transit_share=1.0)
    along_north = 0
    for _ in range(40):
        m = training_mission(base, rng, args)
        assert not random_launch(m, True) and m.timing.episode_s == 300
        along_north += m.area.north_m > m.area.east_m
        axis = 0 if m.area.north_m > m.area.east_m else 1  # the strip's long axis
        length, width = (m.area.north_m, m.area.east_m)[axis], (m.area.north_m, m.area.east_m)[1 - axis]
        assert 350.0 <= width <= 600.0 and length >= 1000.0
        c = np.asarray(m.users.cluster_centers)
        assert len(c) == m.users.count // m.users.cluster_size >= 2
        launch = np.array([m.launch.north_m, m.launch.east_m])
        assert min(launch[axis], length - launch[axis]) == pytest.approx(200.0)  # near one end
        assert launch[1 - axis] == pytest.approx(width / 2)
        first = np.abs(c[:, axis] - launch[axis]).min()
        assert 500.0 - 1e-6 <= first <= 1500.0 + 1e-6  # 0.5-1.5 km before the first cluster
        gaps = np.diff(np.sort(c[:, axis]))
        assert np.all(gaps >= 0.6 * 350.0 - 1e-6) and np.all(gaps <= 1.2 * 350.0 + 1e-6)
        assert np.all((c[:, 1 - axis] >= 0.25 * width - 1e-6) & (c[:, 1 - axis] <= 0.75 * width + 1e-6))
        assert np.all(c[:, axis] <= length - 300.0 + 1e-6)
    assert 5 < along_north < 35  # both orientations drawn
    some = [not random_launch(training_mission(base, rng, ScenarioArgs(transit_share=0.3)), True) for _ in range(200)]
    assert 30 < sum(some) < 90


def test_a_transit_scenario_starts_from_its_launch_line_in_the_twin() -> None:
    base = load_mission(ROOT / "missions" / "paper_urban.yaml")
    m = training_mission(base, np.random.default_rng(2), ScenarioArgs(transit_share=1.0))
    env = CoverageEnv(m, 2, 7, random_launch=random_launch(m, True))
    env.reset()
    centre = env.pos[:, :, :2].mean(1)
    assert torch.allclose(centre, torch.tensor([m.launch.north_m, m.launch.east_m], dtype=centre.dtype).expand(2, 2), atol=1e-3)


def test_the_card_names_long_transits_only_when_they_are_on() -> None:
    off = describe_distribution(True, (15,), {}, ScenarioArgs())
    assert off == describe_distribution(True, (15,), {}) and not any(k.startswith("transit") for k in off)
    on = describe_distribution(True, (15,), {}, ScenarioArgs(transit_share=0.25))
    assert on["transit_share"] == 0.25 and on["transit_m"] == [500.0, 1500.0] and "transit" in on


@pytest.mark.parametrize("argv, said", [
    (["--transit-share", "-0.1"], "--transit-share -0.1: must be in [0, 1]"),
    (["--transit-share", "0.3", "--scenarios", "mission"], "--transit-share needs --scenarios general"),
])
def test_bad_transit_options_are_one_line(tmp_path: Path, monkeypatch, capsys, argv: list[str], said: str) -> None:
    from plmarl_sitl.cli import main

    monkeypatch.chdir(tmp_path)
    assert main(["train", "--out", "x", "--episodes", "1", *argv]) == 2
    err = capsys.readouterr().err
    assert said in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


def test_imitation_on_long_transits_runs(monkeypatch) -> None:
    import dataclasses

    from plmarl_sitl.learning.nn import Actor, BeliefTracker, make_predictor
    from plmarl_sitl.learning.train import scenarios
    from plmarl_sitl.learning.train.imitation import ImitationArgs, imitate_oracle

    @dataclasses.dataclass(frozen=True)
    class ShortTransits(ScenarioArgs):
        transit_m: tuple[float, float] = (500.0, 600.0)
        transit_episode_s: int = 30

    # 30-s episodes on a short strip: the path, not the flight (a 300-s one takes ~50 s here)
    monkeypatch.setattr(scenarios, "ScenarioArgs", ShortTransits)  # what trainer_scenario draws with

    mission = load_mission(ROOT / "missions" / "paper_urban.yaml")
    torch.manual_seed(0)
    tracker = BeliefTracker(make_predictor("hold"), 10, 1.0)
    args = ImitationArgs(rounds=1, episodes_per_round=2, epochs=1, tup_choices=(15,), seed=1, teacher="track",
                         transit_share=1.0)
    res = imitate_oracle(Actor(), tracker, mission, args, log=lambda s: None)
    assert res["episodes"] == 2 and res["final_mse"] == res["final_mse"]
