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


def never_declared(pre: bool) -> tuple[int, int]:
    """(failed UAVs some survivor never knows at the end, live UAVs declared at the end)."""
    m = load_mission(MISSION).with_tup(50)
    env = CoverageEnv(m, 1, suite_twin_seed(7, 0))
    ctl = ServiceController(m)
    ctl.reset()
    obs = env.observe()
    with torch.inference_mode():
        while not env.done:
            obs, _, _ = env.step(ctl.act(obs))
    alive = env.alive[0]
    known = env.gossip.failed[0][alive]  # survivors' rows
    return int((~known[:, ~alive]).any(0).sum()), int(known[:, alive].sum())


@pytest.fixture
def pre_replan():
    plan_mod.DECLARE_PRE_REPLAN = True
    yield
    plan_mod.DECLARE_PRE_REPLAN = False


def test_off_by_default() -> None:
    assert plan_mod.DECLARE_PRE_REPLAN is False and plan_mod.PIN_UNAWARE is False


def test_pre_replan_declares_the_failure_the_guard_hid(pre_replan) -> None:  # noqa: ANN001
    assert never_declared(True) == (0, 0)
