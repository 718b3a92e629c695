"""The session-23 prototype (issue 24), off by default: a failure re-plan that moves as few
survivors as it needs (`model/service.py`, FEWEST_MOVERS, `keep_and_move`)."""

from __future__ import annotations

import numpy as np

from plmarl_sitl.learning.nn.plan import service_grid
from plmarl_sitl.mission import load_mission
from plmarl_sitl.model import service
from plmarl_sitl.model.service import _components, grid_counts, keep_and_move
from plmarl_sitl.twin.env import CoverageEnv

MISSION = "missions/suite/failure_2of6_b.yaml"


def _plan():
    m = load_mission(MISSION)
    grid = service_grid(m)
    env = CoverageEnv(m, 1, 7)
    counts = grid_counts(env.observe().demand[0].double().numpy(), grid)
    pts = grid.place(counts[None], 6)[0][0]
    return grid, counts, pts


def test_the_prototype_is_off_by_default() -> None:
    assert service.FEWEST_MOVERS is False


def test_kept_plans_move_one_survivor_per_step_and_stay_linked_and_spaced() -> None:
    """From the survivors' old points (2 of 6 removed): step k moves exactly one more
    survivor, never serves fewer users, and a plan called feasible is one link component
    with every pair 2 d_safe apart; the same inputs give the same plans (common knowledge)."""
    grid, counts, pts = _plan()
    old = pts[[1, 2, 3, 4]]
    opts = keep_and_move(grid, counts, old, 2)
    again = keep_and_move(grid, counts, old.copy(), 2)
    assert len(opts) >= 2 and len(opts) == len(again)
    for (p, movers, served, feasible), (p2, movers2, served2, _) in zip(opts, again, strict=True):
        assert np.array_equal(p, p2) and movers == movers2 and served == served2
        still = [r for r in range(len(old)) if r not in movers]
        assert np.array_equal(p[still], old[still])
        assert served == float(grid.served(counts[None], p[None])[0])
        if feasible:
            assert (_components(p, grid.link_m) == 0).all()
            d = np.sqrt(((p[:, None] - p[None]) ** 2).sum(-1))
            assert (d[~np.eye(len(p), dtype=bool)] >= grid.apart_m).all()
    assert [len(o[1]) for o in opts] == list(range(len(opts)))
    assert all(b[2] >= a[2] for a, b in zip(opts, opts[1:], strict=False))  # a move is taken only where it gains


def test_a_disconnected_keep_is_not_feasible_and_a_mover_bridges_it() -> None:
    """Two survivors farther apart than R_link: keeping both is infeasible; the first mover
    goes where it rejoins the other."""
    grid, counts, _ = _plan()
    far = np.array([[0.0, 0.0], [grid.cands[-1, 0], grid.cands[-1, 1]]])
    opts = keep_and_move(grid, counts, far, 1)
    assert opts[0][3] is False
    assert opts[1][3] is True and len(opts[1][1]) == 1


def test_copies_that_learn_before_and_after_a_new_map_keep_the_same_plan() -> None:
    """Two copies of a 4-UAV plan learn UAV 1's failure (declared at instant 60): copy 0 at
    second 60, copy 1 at second 90, after a new map (second 75) that moved its plan. The
    fewest-movers step keeps the plan of the epoch, not the copy's plan of now, so both end
    with the same points and slots."""
    from plmarl_sitl.model.plan_motion import PlanMotion
    from plmarl_sitl.model.service import ServiceGrid, TeamPlans
    from plmarl_sitl.model.vehicle import Limits

    grid = ServiceGrid(1000.0, 1000.0, 100.0, 100.0, 350.0, 20.0)
    counts = np.zeros(100)
    for cell in (33, 35, 55, 53):
        counts[cell] = 60
    later = counts.copy()
    later[55], later[66] = 0, 60  # one cluster moves a cell diagonally
    plans = TeamPlans(grid, 4, PlanMotion(Limits(20.0, 5.0, 30.0, 150.0), 100.0, 30.0, 3, lambda t: t % 15 == 0))
    plans.fewest_movers = True
    line = np.stack([np.full(4, 500.0), 440.0 + 40.0 * np.arange(4)], -1)
    plans.start(np.stack([line, line])[None], counts[None])
    failed, since = np.array([False, True, False, False]), np.array([0, 60, 0, 0])
    plans.motion.advance(60, plans.all_targets())
    assert plans.settle(0, 0, failed, since)
    plans.motion.advance(75, plans.all_targets())
    before = plans.points[0, 1].copy()
    plans.on_map(later[None], 75)
    assert not np.array_equal(before, plans.points[0, 1])  # the map moved copy 1's (unaware) plan
    plans.motion.advance(90, plans.all_targets())
    assert plans.settle(0, 1, failed, since)
    assert np.array_equal(plans.slot[0, 0], plans.slot[0, 1]) and plans.slot[0, 0, 1] == -1
    assert np.array_equal(np.nan_to_num(plans.points[0, 0]), np.nan_to_num(plans.points[0, 1]))
