"""Session 22's twin-only prototypes (issue 24, off by default): the pinned placement
(`model/service.py::pinned_place`, `PIN_UNAWARE`) and the declaration of a guard-blocked
silent teammate at its pre-re-plan positions too (`DECLARE_PRE_REPLAN`)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from plmarl_sitl.learning.eval.controllers import ServiceController
from plmarl_sitl.learning.nn import plan as plan_mod
from plmarl_sitl.learning.nn.plan import service_grid
from plmarl_sitl.learning.train.seeds import suite_twin_seed
from plmarl_sitl.mission import load_mission
from plmarl_sitl.model.service import pinned_place
from plmarl_sitl.twin.env import CoverageEnv

MISSION = "missions/suite/failure_2of6_a.yaml"


def test_pinned_place_starts_at_the_pins_and_keeps_every_pick_linked() -> None:
    grid = service_grid(load_mission(MISSION))
    counts = np.zeros(grid.rows * grid.cols)
    counts[[5, 40, 77]] = [30, 50, 20]
    pins = np.array([[101.0, 99.0], [400.0, 420.0]])
    pts = pinned_place(grid, counts, pins, 4)
    assert pts.shape == (4, 2)
    assert np.abs(pts[:2] - pins).max() <= 25.0  # each pin at its nearest candidate
    for k in range(2, 4):
        d = np.sqrt(((pts[:k] - pts[k]) ** 2).sum(-1))
        assert d.min() <= grid.link_m and d.min() >= grid.apart_m


def never_known(episodes: int = 10) -> int:
    """The failed UAVs some survivor still does not know at the end (failure_2of6_a, seed 7's episodes, T_up 50)."""
    m = load_mission(MISSION).with_tup(50)
    env = CoverageEnv(m, episodes, suite_twin_seed(7, 0))
    ctl = ServiceController(m)
    ctl.reset()
    obs = env.observe()
    with torch.inference_mode():
        while not env.done:
            obs, _, _ = env.step(ctl.act(obs))
    dead = ~env.alive
    unknown = ~env.gossip.failed & dead.unsqueeze(1) & env.alive.unsqueeze(-1)  # [e, survivor, dead one]
    return int(unknown.any(1).sum())


@pytest.fixture
def pre_replan():
    saved = plan_mod.DECLARE_PRE_REPLAN, plan_mod.PRE_REPLAN_MISSED, plan_mod.PRE_REPLAN_SEEN
    plan_mod.DECLARE_PRE_REPLAN, plan_mod.PRE_REPLAN_MISSED, plan_mod.PRE_REPLAN_SEEN = True, 1, True
    yield
    plan_mod.DECLARE_PRE_REPLAN, plan_mod.PRE_REPLAN_MISSED, plan_mod.PRE_REPLAN_SEEN = saved


def test_off_by_default() -> None:
    assert not (plan_mod.DECLARE_PRE_REPLAN or plan_mod.PRE_REPLAN_SEEN or plan_mod.PIN_UNAWARE or plan_mod.PIN_QUIET)


def test_pre_replan_declares_the_failures_the_guard_hid(pre_replan) -> None:  # noqa: ANN001
    """Session 22's c4: on these episodes the guard leaves 3 failed UAVs unknown to the end
    (docs/results/issue24/session22/fail); testing them at their pre-re-plan points declares them."""
    assert never_known() == 0
