"""Local failure repairs (`failure_replan: local`, the default, model/repairs.py): each failed UAV's
point is dropped and only its neighbours in the first plan may move; copies that know the same
failures hold the same plan; the re-solve is kept for where no repair is feasible and for a swarm
not yet on station (a failure in transit)."""

from __future__ import annotations

import numpy as np
import pytest

from plmarl_sitl.learning.nn.plan import repairer_of, service_grid
from plmarl_sitl.mission import load_mission
from plmarl_sitl.model.plan_motion import PlanMotion
from plmarl_sitl.model.repairs import (
    MOVERS_K,
    STATION_M,
    keep_and_move,
    link_components,
    local_repairs,
    on_station,
    repair,
)
from plmarl_sitl.model.service import ServiceGrid, TeamPlans, grid_counts
from plmarl_sitl.model.vehicle import Limits
from plmarl_sitl.twin.env import CoverageEnv

MISSION = "missions/suite/failure_2of6_b.yaml"


@pytest.fixture(scope="module")
def first_plan() -> tuple[ServiceGrid, np.ndarray, np.ndarray, np.ndarray]:
    """The mission's grid, its first map, its first plan (6, 2) and predicted positions near it."""
    m = load_mission(MISSION)
    grid = service_grid(m)
    counts = grid_counts(CoverageEnv(m, 1, 7).observe().demand[0].double().numpy(), grid)
    p0 = grid.place(counts[None], 6)[0][0]
    return grid, counts, p0, p0 + 10.0


def neighbours(grid: ServiceGrid, p0: np.ndarray, f: int, failed: set[int]) -> list[int]:
    d = np.sqrt(((p0 - p0[f]) ** 2).sum(-1))
    return [i for i in range(len(p0)) if d[i] <= grid.link_m and i != f and i not in failed]


def test_the_default_repairs_and_the_re_solve_is_chosen_by_the_mission() -> None:
    m = load_mission(MISSION)
    assert m.failure_replan == "local" and repairer_of(m) is local_repairs
    assert repairer_of(m.with_failure_replan("resolve")) is None


def test_a_repair_moves_only_allowed_rows_and_at_most_movers_k(first_plan) -> None:  # noqa: ANN001
    grid, counts, p0, src = first_plan
    ident = np.arange(6)
    for f in range(6):
        nbrs = neighbours(grid, p0, f, {f})
        out = repair(grid, counts, p0, ident, f, src, np.flatnonzero(np.isin(ident, nbrs)))
        assert out is not None
        pts, who, movers = out
        assert who.tolist() == [i for i in range(6) if i != f]
        assert set(movers) <= set(nbrs) and len(movers) <= MOVERS_K
        for i, q in zip(who, pts, strict=True):
            if int(i) not in movers:
                assert np.array_equal(q, p0[i])
        assert (link_components(pts, grid.link_m) == 0).all()  # one link component
        d = np.sqrt(((pts[:, None] - pts[None]) ** 2).sum(-1))
        assert (d[~np.eye(5, dtype=bool)] >= grid.apart_m).all()


def test_keep_and_move_starts_from_the_kept_plan(first_plan) -> None:  # noqa: ANN001
    grid, counts, p0, _ = first_plan
    options = keep_and_move(grid, counts, p0[1:], MOVERS_K)
    assert np.array_equal(options[0].points, p0[1:]) and options[0].movers == []
    assert options[0].served == pytest.approx(float(grid.served(counts[None], p0[None, 1:])[0]))
    assert all(len(o.movers) == k for k, o in enumerate(options))


def test_two_failures_with_disjoint_neighbours_commute(first_plan) -> None:  # noqa: ANN001
    """Failures 0 and 3 of the first plan have disjoint neighbours: the repairs in either order
    give the same plan, which `local_repairs` (increasing identity order) gives too."""
    grid, counts, p0, src = first_plan
    failed = {0, 3}
    n0, n3 = neighbours(grid, p0, 0, failed), neighbours(grid, p0, 3, failed)
    assert n0 and n3 and not set(n0) & set(n3)
    ident = np.arange(6)

    def one(pts: np.ndarray, who: np.ndarray, f: int, nbrs: list[int]) -> tuple[np.ndarray, np.ndarray]:
        out = repair(grid, counts, pts, who, f, src, np.flatnonzero(np.isin(who, nbrs)))
        assert out is not None
        return out[0], out[1]

    a = one(*one(p0, ident, 0, n0), 3, n3)
    b = one(*one(p0, ident, 3, n3), 0, n0)
    assert np.array_equal(a[0], b[0]) and a[1].tolist() == b[1].tolist() == [1, 2, 4, 5]
    mask = np.isin(np.arange(6), sorted(failed))
    assert np.array_equal(local_repairs(grid, counts, p0, mask, src), a[0])


def test_no_live_neighbour_gives_the_re_solve_back(first_plan) -> None:  # noqa: ANN001
    grid, counts, p0, src = first_plan
    f = 0
    failed = np.zeros(6, dtype=bool)
    failed[[f, *neighbours(grid, p0, f, set())]] = True
    assert local_repairs(grid, counts, p0, failed, src) is None


def test_a_swarm_not_on_station_is_re_solved(first_plan) -> None:  # noqa: ANN001
    """A failure in transit: one survivor predicted farther than STATION_M from its first-plan
    point gives the re-solve back; the same failure on station is repaired. A failed UAV's own
    position does not count."""
    grid, counts, p0, src = first_plan
    failed = np.zeros(6, dtype=bool)
    failed[0] = True
    assert on_station(p0, failed, src) and local_repairs(grid, counts, p0, failed, src) is not None
    far = src.copy()
    far[3] = p0[3] + [STATION_M + 1.0, 0.0]
    assert not on_station(p0, failed, far) and local_repairs(grid, counts, p0, failed, far) is None
    near = src.copy()
    near[3] = p0[3] + [STATION_M - 1.0, 0.0]
    near[0] = p0[0] + [5 * STATION_M, 0.0]  # the failed one, wherever it was
    assert on_station(p0, failed, near)


def plans(repairer) -> TeamPlans:  # noqa: ANN001
    """Four UAVs over four crowds of a 1 km square, a plan copy per agent of one team."""
    grid = ServiceGrid(1000.0, 1000.0, 100.0, 100.0, 350.0, 20.0)
    counts = np.zeros(100)
    counts[[33, 35, 55, 53]] = 60
    out = TeamPlans(grid, 4, PlanMotion(Limits(20.0, 5.0, 30.0, 150.0), 100.0, 30.0, 3, lambda t: t % 15 == 0), repairer)
    line = np.stack([np.full(4, 500.0), 440.0 + 40.0 * np.arange(4)], -1)
    out.start(np.stack([line] * 4)[None], counts[None])
    out.motion.advance(60, out.all_targets())
    return out


def test_a_copy_that_knows_one_failure_moves_only_its_neighbours() -> None:
    """With local repairs a copy that learns of UAV 1 keeps every survivor that is not 1's
    neighbour at its first-plan point; two copies told the same hold the same plan; the
    re-solve (the default) is another plan here."""
    local, whole = plans(local_repairs), plans(None)
    p0 = local.all_targets()[0, 0].copy()
    one = np.array([False, True, False, False])
    for copy in (0, 2):
        assert local.settle(0, copy, one, np.array([0, 60, 0, 0]))
        assert whole.settle(0, copy, one, np.array([0, 60, 0, 0]))
    after = local.all_targets()[0, 0]
    assert np.isnan(after[1]).all()
    nbrs = neighbours(local.grid, p0, 1, {1})
    moved = [i for i in (0, 2, 3) if not np.array_equal(after[i], p0[i])]
    assert set(moved) <= set(nbrs) and len(moved) <= MOVERS_K
    assert np.array_equal(np.nan_to_num(local.all_targets()[0, 2]), np.nan_to_num(after))
    # a copy that has not learnt it still flies the first plan
    assert np.array_equal(local.all_targets()[0, 1], p0)
    assert not np.array_equal(np.nan_to_num(whole.all_targets()[0, 0]), np.nan_to_num(after))


def test_a_bad_failure_replan_value_is_one_clear_error(tmp_path) -> None:  # noqa: ANN001
    from plmarl_sitl.errors import UserError

    path = tmp_path / "m.yaml"
    path.write_text("name: x\nfailure_replan: nearest\n")
    with pytest.raises(UserError, match="failure_replan"):
        load_mission(path)


def test_the_twin_flies_the_re_solve_as_a_method() -> None:
    """`service-resolve` is `service` with failure_replan: resolve: the same episode, the same
    coverage until the failure (100 s), another after it (a real twin episode, T_up 50)."""
    from plmarl_sitl.learning.eval.evaluate import controller_factory, run_method

    m = load_mission("missions/suite/failure_2of6_b.yaml").with_tup(50)
    local, whole = (run_method(m, controller_factory(meth, {}), 1, 8, batch=1).trace[0]
                    for meth in ("service", "service-resolve"))
    assert np.array_equal(local[:100], whole[:100])
    assert not np.array_equal(local[100:], whole[100:])
