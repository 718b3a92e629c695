"""The team plan's other placements (model/placement.py, issue 24.3): the search serves at
least what the greedy serves and keeps the plan's rules (connected, 2 d_safe apart); its
screened sweep equals the plain sequential sweep; the learnt placement, with a scorer that
ranks as the greedy does, is the greedy; a scorer gives the same picks in every copy; and
the twin's plan and the deployed agent's take the mission's placement from one place."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from plmarl_sitl.deploy.agent.plan import AgentPlan
from plmarl_sitl.learning.nn.placement import PlacementScorer, export, load_placement_scorer
from plmarl_sitl.learning.nn.plan import ServiceTargets, service_grid
from plmarl_sitl.mission import load_mission
from plmarl_sitl.model.placement import LARGE_N, LearnedPlacement, LocalSearch, PickState, SearchPlacement, components

ROOT = Path(__file__).resolve().parents[2]
MISSION = ROOT / "missions" / "suite" / "failure_2of6_a.yaml"


def maps(grid, count: int, seed: int) -> np.ndarray:  # noqa: ANN001 - ServiceGrid
    """Clustered random maps (K,): a few Gaussian blobs of users on the grid's cells."""
    rng = np.random.default_rng(seed)
    out = np.zeros((count, grid.rows * grid.cols))
    for m in out.reshape(count, grid.rows, grid.cols):
        for _ in range(int(rng.integers(2, 6))):
            c = rng.uniform(2, grid.rows - 3, 2)
            pts = np.clip(np.rint(c + rng.normal(0, rng.uniform(0.7, 2.0), (int(rng.integers(20, 90)), 2))), 0, grid.rows - 1)
            np.add.at(m, (pts[:, 0].astype(int), pts[:, 1].astype(int)), 1.0)
    return out


def connected(xy: np.ndarray, link_m: float) -> bool:
    return bool((components(xy, link_m, -1) == 0).all())


def test_search_serves_at_least_the_greedy_and_keeps_the_plans_rules() -> None:
    grid = service_grid(load_mission(MISSION))
    counts = maps(grid, 12, 0)
    better = 0
    for n in (3, 4, 6, 9):
        greedy_pts, greedy_served = grid.greedy_place(counts, n)
        pts, served = SearchPlacement().place(grid, counts, n)
        assert (served >= greedy_served).all()
        better += int((served > greedy_served).sum())
        assert np.allclose(grid.served(counts, pts), served)  # `served` is what the points serve
        for p in pts:
            d = np.sqrt(((p[:, None] - p[None]) ** 2).sum(-1)) + np.eye(n) * 1e9
            assert d.min() >= grid.apart_m and connected(p, grid.link_m)
    assert better > 0  # it does find better plans than the greedy on such maps


def test_screened_sweep_equals_the_plain_sequential_sweep(monkeypatch: pytest.MonkeyPatch) -> None:
    grid = service_grid(load_mission(MISSION))
    counts = maps(grid, 10, 1)
    screened = [SearchPlacement().place(grid, counts, n) for n in (4, 7)]
    monkeypatch.setattr(LocalSearch, "screen", lambda self, w, picks, cnt: np.ones(len(picks), dtype=bool))
    monkeypatch.setattr(LocalSearch, "lattice_ok", lambda self, w: False)  # the sparse form's sweep, every point
    plain = [SearchPlacement().place(grid, counts, n) for n in (4, 7)]
    for (a, sa), (b, sb) in zip(screened, plain, strict=True):
        assert np.array_equal(a, b) and np.array_equal(sa, sb)


def test_search_above_large_n_is_the_greedy() -> None:
    grid = service_grid(load_mission(MISSION))
    counts = maps(grid, 2, 2)
    assert np.array_equal(SearchPlacement().place(grid, counts, LARGE_N + 1)[0], grid.greedy_place(counts, LARGE_N + 1)[0])


class RankScorer(torch.nn.Module):
    """Ranks as the greedy: the candidate of rank 0 (the largest marginal gain) first."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return -x[:, 6]


def test_learnt_placement_with_the_greedys_ranking_is_the_greedy(tmp_path: Path) -> None:
    torch.jit.save(torch.jit.script(RankScorer()), str(tmp_path / "rank.pt"))
    grid = service_grid(load_mission(MISSION))
    counts = maps(grid, 8, 3)
    learned = LearnedPlacement(load_placement_scorer(tmp_path / "rank.pt"))
    for n in (1, 4, 6):
        a, sa = learned.place(grid, counts, n)
        b, sb = grid.greedy_place(counts, n)
        assert np.array_equal(a, b) and np.array_equal(sa, sb)


def test_a_scorer_gives_the_same_picks_in_every_copy(tmp_path: Path) -> None:
    """Two copies loaded from one file, fed the same map alone and in a batch: the same bits."""
    torch.manual_seed(0)
    export(PlacementScorer(16), tmp_path / "s.pt")
    grid = service_grid(load_mission(MISSION))
    counts = maps(grid, 4, 4)
    one = LearnedPlacement(load_placement_scorer(tmp_path / "s.pt"))
    two = LearnedPlacement(load_placement_scorer(tmp_path / "s.pt"))
    batch = one.place(grid, counts, 5)
    for i in range(len(counts)):
        alone = two.place(grid, counts[i : i + 1], 5)
        assert np.array_equal(alone[0][0], batch[0][i]) and alone[1][0] == batch[1][i]
    state = PickState(grid, counts[0], 5)
    x = torch.from_numpy(state.features(state.top()))
    assert torch.equal(one.scorer(x), two.scorer(x)) and x.dtype == torch.float64


def test_twin_and_agent_take_the_missions_placement_from_one_place() -> None:
    m = load_mission(MISSION)
    for placement, kind in (("greedy", type(None)), ("search", SearchPlacement), ("learned", LearnedPlacement)):
        mp = m.with_placement(placement)
        twin, agent = ServiceTargets(mp).grid, AgentPlan(mp, 0).grid
        assert twin is agent and isinstance(twin.placer, kind)


def test_a_missing_or_broken_scorer_is_a_one_line_error(tmp_path: Path) -> None:
    from plmarl_sitl.errors import UserError

    with pytest.raises(UserError, match="needs the scorer"):
        load_placement_scorer(tmp_path / "none.pt")
    (tmp_path / "bad.pt").write_bytes(b"not a model")
    with pytest.raises(UserError, match="not a TorchScript placement scorer"):
        load_placement_scorer(tmp_path / "bad.pt")
