"""`service-track` / `pl-marl-track` (issue 24.3, session 19): the plan point follows the sensed users."""

import dataclasses

import numpy as np
import torch

from plmarl_sitl.learning.eval.evaluate import TRACK_METHOD_M, controller_factory, needed_policies, run_method, tracking
from plmarl_sitl.learning.nn.io import load_policy
from plmarl_sitl.mission import load_mission

PAPER = load_mission("missions/paper_urban.yaml")
# Fast groups walking far (as the probes of docs/results/issue24/session19/move/; a training seed)
MOVING = dataclasses.replace(PAPER, users=dataclasses.replace(PAPER.users, mobility="rpgm", max_speed_mps=4.0,
                                                              rpgm_range_m=400.0))


def test_tracking_sets_the_methods_bound_unless_the_mission_has_one():
    assert tracking(PAPER).track_sensed_m == TRACK_METHOD_M
    assert tracking(PAPER.with_track_sensed(12.0)).track_sensed_m == 12.0
    assert needed_policies(["pl-marl-track"]) == {"pl-marl"}


def test_following_the_sensed_users_covers_more_of_walking_crowds():
    """Paired episodes: the plan follower, and the shipped PL-MARL policy, with the point moved
    toward the sensed users cover more than the plan follower on its stale map."""
    torch.set_num_threads(1)
    loaded = {"pl-marl": load_policy("policies/pl-marl")}
    cov = {m: run_method(MOVING.with_tup(15), controller_factory(m, loaded), 4, 4242, batch=4).coverage
           for m in ("service", "service-track", "pl-marl-track")}
    for m in ("service-track", "pl-marl-track"):
        assert np.all(cov[m] > cov["service"]), (m, cov)
