"""The launch line every plan copy starts from, at N = 100 (scale_100): each agent hears only
its two neighbours at the first instant (SINR with 100 transmitters), and SITL positions
carry ~1 cm of quantisation. A fit through 3 states extrapolates that to decimetres at the
line's far end, and copies with different lines broke the lattice's exact assignment ties
differently (22 points held twice in SITL, none in the twin). Heard positions on the
mission's own line give every copy that line, to the bit."""

from __future__ import annotations

import numpy as np
import torch

from plmarl_sitl.deploy.agent.plan import AgentPlan
from plmarl_sitl.learning.nn.plan import heard_launch
from plmarl_sitl.mission import load_mission
from plmarl_sitl.model.service import LAUNCH_ROUND_M, mission_launch_xy
from plmarl_sitl.twin.env import CoverageEnv

SCALE_100 = load_mission("missions/scale_100.yaml")


def quantised(xy: np.ndarray, seed: int = 0) -> np.ndarray:
    """Positions as SITL agents hear them: off by up to 1 cm."""
    rng = np.random.default_rng(seed)
    return xy + rng.choice([-0.01, 0.0, 0.01], size=xy.shape)


def neighbours_only(me: int, n: int) -> np.ndarray:
    heard = np.zeros(n, dtype=bool)
    heard[[j for j in (me - 1, me + 1) if 0 <= j < n]] = True
    return heard


def test_every_copy_takes_the_mission_line_from_two_neighbours_heard_with_1cm_errors() -> None:
    nominal = mission_launch_xy(SCALE_100)
    n = len(nominal)
    held = quantised(nominal)
    lines = [heard_launch(held[i], held, neighbours_only(i, n), i, nominal) for i in range(n)]
    want = np.round(nominal / LAUNCH_ROUND_M) * LAUNCH_ROUND_M
    assert all(np.array_equal(line, want) for line in lines)
    # Without the mission's line the fits differ by decimetres (the SITL-to-twin gap at N = 100).
    fits = [heard_launch(held[i], held, neighbours_only(i, n), i) for i in range(n)]
    assert max(np.abs(f - want).max() for f in fits) > 0.1


def test_a_launch_away_from_the_mission_line_is_still_fitted() -> None:
    nominal = mission_launch_xy(SCALE_100)
    n = len(nominal)
    moved = nominal + np.array([5.0, -3.0])  # elsewhere (a twin's random launch, a real take-off)
    line = heard_launch(moved[41], moved, neighbours_only(41, n), 41, nominal)
    assert np.allclose(line, moved, atol=LAUNCH_ROUND_M)


def test_an_agent_plans_the_twins_point_from_states_heard_with_1cm_errors() -> None:
    env = CoverageEnv(SCALE_100, 1, 0)
    obs = env.observe()
    me = 41  # its point is one of an exact north/south tie of the lattice
    exact = obs.nbr_state[0, me]
    heard = exact.clone()
    heard[me - 1, 1] += 0.01
    heard[me + 1, 1] -= 0.01
    demand = (0.0, obs.demand[0])
    want = AgentPlan(SCALE_100, me).target(0, obs.ego[0, me], exact, obs.nbr_t_rx[0, me], demand)
    got = AgentPlan(SCALE_100, me).target(0, obs.ego[0, me], heard, obs.nbr_t_rx[0, me], demand)
    assert want is not None and torch.equal(got, want)
