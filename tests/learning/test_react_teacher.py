"""Issue 24 part 3: the CTDE teacher that reacts at once (learning/train/teacher.py), the
failure curriculum of its imitation, and the dead-reckoning ablation's re-plans."""

from __future__ import annotations

import numpy as np
import torch

from plmarl_sitl.learning.eval.controllers import ServiceController
from plmarl_sitl.learning.eval.evaluate import controller_factory
from plmarl_sitl.learning.nn.io import load_policy
from plmarl_sitl.learning.train.imitation import scripted_failures
from plmarl_sitl.learning.train.teacher import ReactTargets
from plmarl_sitl.mission import load_mission
from plmarl_sitl.twin.env import CoverageEnv


def test_the_teacher_re_plans_the_second_a_uav_fails_and_every_copy_agrees() -> None:
    """failure_2of6_a: UAVs 1 and 4 fail at t = 100 s. The teacher's copies hold the true
    failed set with epoch = the first decision after the failure, the same points and slots
    in every survivor's copy, while the plan follower (which learns from missed instants)
    still flies the plan of t = 0 then."""
    m = load_mission("missions/suite/failure_2of6_a.yaml").with_tup(15)
    env = CoverageEnv(m, 2, 1_000_000_321)
    teacher, service = ReactTargets.of(m), ServiceController(m)
    obs = env.observe()
    seen_at = None
    while obs.t <= 110:
        target = teacher.update_true(obs)
        act = service.act(obs)
        if seen_at is None and not bool(obs.alive[:, 1].all()):
            seen_at = obs.t
            assert (service.targets.plans.epoch == 0).all()  # no declaration yet
        obs, _, _ = env.step(torch.where(obs.alive.unsqueeze(-1), teacher.accel(obs.ego, target), act))
    assert seen_at is not None and 100 <= seen_at <= 103
    plans = teacher.plans
    for b in range(2):
        alive = np.flatnonzero(env.alive[b].numpy())
        assert alive.tolist() == [0, 2, 3, 5]
        for a in alive:
            assert plans.failed[b, a].tolist() == [False, True, False, False, True, False]
            assert plans.epoch[b, a] == seen_at
            assert np.array_equal(plans.slot[b, a], plans.slot[b, alive[0]])
            assert np.array_equal(np.nan_to_num(plans.points[b, a]), np.nan_to_num(plans.points[b, alive[0]]))
    assert teacher.replans_done == 2 * 4


def test_scripted_failures_fail_one_or_two_but_leave_two() -> None:
    rng = np.random.default_rng(0)
    base = load_mission("missions/paper_urban.yaml")
    ks = set()
    for n in (3, 4, 6, 8):
        m0 = base.__class__(**{**base.__dict__, "n_uavs": n})
        for _ in range(20):
            m = scripted_failures(m0, rng, (20, 160))
            k = len(m.failures)
            ks.add(k)
            assert 1 <= k <= min(2, n - 2)
            assert len({f.uav for f in m.failures}) == k and all(0 <= f.uav < n for f in m.failures)
            assert len({f.at_s for f in m.failures}) == 1 and 20 <= m.failures[0].at_s <= 160
    assert ks == {1, 2}


def test_dead_reckoning_re_plans_from_constant_velocity_and_pl_marl_from_the_plan() -> None:
    """The ablation replaces the predictor wherever PL-MARL uses one, the re-plan's assignment
    positions included."""
    m = load_mission("missions/suite/failure_transit.yaml")
    loaded = {"pl-marl": load_policy("policies/pl-marl", m)}
    env = CoverageEnv(m, 1, 1_000_000_007)
    dr = controller_factory("dead-reckoning", loaded)(env)
    pl = controller_factory("pl-marl", loaded)(env)
    assert dr.perceive.plan.sources == "cv"
    assert pl.perceive.plan.sources == "plan"


def test_a_copy_that_counts_everyone_failed_keeps_its_plan() -> None:
    """Only false declarations can make a live agent's copy count every identity failed (the
    constant-velocity ablation did, flying a policy that leaves the plan's nominal path); the
    re-plan then keeps the plan it had instead of placing zero points."""
    m = load_mission("missions/suite/failure_transit.yaml")
    env = CoverageEnv(m, 1, 1_000_000_011)
    ctl = ServiceController(m)
    obs = env.observe()
    for _ in range(3):
        obs, _, _ = env.step(ctl.act(obs))
    plans = ctl.targets.plans
    before = plans.all_targets()[0, 0].copy()
    everyone = np.ones(m.n_uavs, dtype=bool)
    plans.replan(0, 0, everyone, 3)
    assert plans.failed[0, 0].all() and plans.epoch[0, 0] == 3
    assert np.array_equal(np.nan_to_num(plans.all_targets()[0, 0]), np.nan_to_num(before))
