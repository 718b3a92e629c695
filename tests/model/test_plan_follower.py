"""The plan follower's command, and a learnt policy's UAV flying it in transit (mission
`transit_plan_m`, model/plan_follower.py): in the twin the UAV then flies exactly the
plan-aware nominal its teammates predict it by (model/plan_motion.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from plmarl_sitl.learning.eval.controllers import LearnedController
from plmarl_sitl.learning.nn.io import load_policy
from plmarl_sitl.mission import load_mission
from plmarl_sitl.model.plan_follower import PlanFollower
from plmarl_sitl.twin.env import CoverageEnv

ROOT = Path(__file__).resolve().parents[2]
TRANSIT = ROOT / "missions" / "suite" / "failure_transit.yaml"


def test_in_transit_switches_at_the_distance() -> None:
    m = load_mission(TRANSIT).with_transit_plan(50.0)
    f = PlanFollower(m)
    ego = torch.tensor([[0.0, 0.0, -60.0, 0.0, 0.0, 0.0], [0.0, 0.0, -60.0, 0.0, 0.0, 0.0]])
    point = torch.tensor([[40.0, 0.0], [60.0, 0.0]])  # 40 m: on station; 60 m: in transit
    policy = torch.full((2, 3), 0.25)
    out = f.in_transit(policy, ego, point)
    assert torch.equal(out[0], policy[0])
    assert torch.equal(out[1], f.accel(ego[1:], point[1:])[0]) and not torch.equal(out[1], policy[1])
    off = PlanFollower(m.with_transit_plan(0.0))
    assert torch.equal(off.in_transit(policy, ego, point), policy)  # 0: the policy everywhere
    assert torch.equal(f.in_transit(policy, ego, None), policy)  # no plan point: the policy


def _deviation_in_transit(transit_m: float) -> float:
    """The largest distance (m) between a UAV and its own plan-aware nominal over the first 30 s
    of a far launch (before any failure), pl-marl in the twin."""
    m = load_mission(TRANSIT).with_tup(50).with_transit_plan(transit_m)
    lp = load_policy(ROOT / "policies" / "pl-marl", m)
    env = CoverageEnv(m, 2, 5)
    ctl = LearnedController(lp.tracker, lp.policy, m)
    ctl.reset()
    obs, worst = env.observe(), 0.0
    with torch.inference_mode():
        while obs.t < 30:
            accel = ctl.act(obs)
            nominal = ctl.perceive.plan.plans.motion.now  # (B, A, n, 6): each copy's team, at obs.t
            n = nominal.shape[2]
            own = nominal[:, np.arange(n), np.arange(n), :2]
            worst = max(worst, float(np.abs(obs.ego[..., :2].double().numpy() - own).max()))
            obs, _, _ = env.step(accel)
    return worst


def test_a_learnt_policy_in_transit_flies_the_nominal() -> None:
    assert _deviation_in_transit(50.0) < 1e-3  # the plan follower's command: the nominal itself
    assert _deviation_in_transit(0.0) > 5.0  # the policy steers off it
