"""The references: the clairvoyant is never below the greedy on seeded episodes (the greedy's
plan is one of its candidates), its plans are connected and 2 d_safe apart, local improvement
never loses users, and the best reference per episode is what the reports say it is."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from plmarl_sitl.learning.eval.references import best_reference, pairwise_wins
from plmarl_sitl.mission import load_mission
from plmarl_sitl.twin.clairvoyant import ClairvoyantController
from plmarl_sitl.twin.env import CoverageEnv
from plmarl_sitl.twin.greedy import GreedyController
from plmarl_sitl.twin.rollout import rollout

PAPER = load_mission("missions/paper_urban.yaml")
RANDOM = load_mission("missions/suite/random_layout.yaml")


@pytest.fixture(autouse=True)
def one_thread():  # noqa: ANN201 - as the suite runs them; two threads on small tensors cost 10x under load
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def _steady(mission, make, episodes: int, seed: int, failure_prob: float = 0.0) -> np.ndarray:  # noqa: ANN001
    runs = rollout(mission, make, episodes, seed, batch=episodes, failure_prob=failure_prob)
    return torch.cat([r.coverage[:, 50:].mean(-1) for r in runs]).numpy()


@pytest.mark.parametrize(("mission", "seed", "failure_prob"), [(PAPER, 3, 0.0), (RANDOM, 11, 0.0), (RANDOM, 12, 1.0)],
                         ids=["paper", "random", "random-failure"])
def test_clairvoyant_is_not_below_the_greedy_on_seeded_episodes(mission, seed: int, failure_prob: float) -> None:  # noqa: ANN001
    greedy = _steady(mission, GreedyController, 4, seed, failure_prob)
    clair = _steady(mission, ClairvoyantController, 4, seed, failure_prob)
    assert (clair >= greedy - 1e-6).all(), (clair, greedy)
    assert clair.mean() > greedy.mean()  # and it is a stronger reference, not the same one


def test_plans_are_connected_apart_and_improvement_never_loses_users() -> None:
    env = CoverageEnv(RANDOM, 6, seed=5)
    env.reset()
    ctl = ClairvoyantController(env)
    users = env.users.xy.double()
    plans = ctl.greedy_variants(users, env.n)
    better = ctl.improve(users, plans)

    def served(p: torch.Tensor) -> torch.Tensor:
        return ctl.covers(users, ctl.cells[p]).any(2).sum(-1)

    assert (served(better) >= served(plans)).all()
    assert (served(better) > served(plans)).any()  # it does move points somewhere
    pts = ctl.cells[better]  # (b, V, k, 2)
    d = torch.cdist(pts, pts)
    k = pts.shape[-2]
    off = ~torch.eye(k, dtype=torch.bool)
    assert (d[..., off] >= 2 * RANDOM.radii.safe_m - 1e-9).all()
    link = (d <= 0.95 * RANDOM.radii.comm_m).double()
    reach = torch.linalg.matrix_power(link + torch.eye(k, dtype=torch.float64), k)
    assert (reach > 0).all()  # every plan's link graph is connected


def test_best_reference_per_episode_and_its_label() -> None:
    t = np.zeros((3, 5))
    runs = {"greedy": (np.array([0.9, 0.8, 0.7]), t + 1), "clairvoyant": (np.array([0.95, 0.8, 0.6]), t + 2),
            "service": (np.array([0.5, 0.85, 0.75]), t + 3), "pl-marl": (np.array([1.0, 1.0, 1.0]), t + 4)}
    best = best_reference(runs)
    assert best is not None
    np.testing.assert_allclose(best.coverage, [0.95, 0.85, 0.75])  # a learnt method is never a reference
    assert best.which.tolist() == ["clairvoyant", "service", "service"]
    np.testing.assert_array_equal(best.trace[:, 0], [2, 3, 3])  # the transient uses that reference's trace
    assert best.label() == "service 2/3, clairvoyant 1/3"
    assert best_reference({"pl-marl": runs["pl-marl"]}) is None
    wins = pairwise_wins({k: v[0] for k, v in runs.items()})
    assert wins["clairvoyant>greedy"] == pytest.approx(1 / 3) and "pl-marl>greedy" not in wins
