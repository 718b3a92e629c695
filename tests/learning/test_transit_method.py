"""`pl-marl-transit` (session 28): the PL-MARL policy with the plan follower's command in transit
(mission key `transit_plan_m`, model/plan_follower.py)."""

import numpy as np
import torch

from plmarl_sitl.learning.eval.evaluate import (
    TRANSIT_METHOD_M,
    controller_factory,
    in_transit,
    needed_policies,
    run_method,
)
from plmarl_sitl.learning.nn.io import load_policy
from plmarl_sitl.mission import load_mission

TRANSIT = load_mission("missions/suite/failure_transit.yaml").with_tup(50)


def test_in_transit_sets_the_methods_distance_unless_the_mission_has_one():
    assert in_transit(TRANSIT).transit_plan_m == TRANSIT_METHOD_M
    assert in_transit(TRANSIT.with_transit_plan(80.0)).transit_plan_m == 80.0
    assert needed_policies(["pl-marl-transit"]) == {"pl-marl"}


def test_the_method_is_the_mission_key_and_changes_a_far_launch():
    """Paired episodes of a far launch: the method flies exactly what the mission key flies, and
    not what the policy flies everywhere."""
    torch.set_num_threads(1)
    loaded = {"pl-marl": load_policy("policies/pl-marl")}

    def cov(method, mission):  # noqa: ANN001, ANN202
        return run_method(mission, controller_factory(method, loaded), 2, 4242, batch=2).coverage

    method = cov("pl-marl-transit", TRANSIT)
    assert np.array_equal(method, cov("pl-marl", TRANSIT.with_transit_plan(TRANSIT_METHOD_M)))
    assert not np.array_equal(method, cov("pl-marl", TRANSIT))
