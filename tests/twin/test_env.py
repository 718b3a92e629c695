"""The vectorised environment: determinism, observations, failures, controllers."""

import dataclasses

import numpy as np
import torch

from plmarl_sitl.mission import Failure, Launch, load_mission
from plmarl_sitl.model.coverage import SENSING_FEATURES
from plmarl_sitl.twin.env import CoverageEnv
from plmarl_sitl.twin.greedy import GreedyController
from plmarl_sitl.twin.heuristic import HeuristicController
from plmarl_sitl.twin.rollout import run_episodes

MISSION = load_mission("missions/paper_urban.yaml")


def _rollout(env, steps, seed=0):
    g = torch.Generator().manual_seed(seed)
    out = []
    for _ in range(steps):
        obs, r, info = env.step((torch.rand(env.num_envs, env.n, 3, generator=g) * 2 - 1) * 5)
        out.append((obs.ego.clone(), r.clone(), info.coverage.clone()))
    return out


def test_same_seed_same_numbers_different_seed_differs():
    a = _rollout(CoverageEnv(MISSION, 3, seed=7), 10)
    b = _rollout(CoverageEnv(MISSION, 3, seed=7), 10)
    c = _rollout(CoverageEnv(MISSION, 3, seed=8), 10)
    assert all(torch.equal(x, y) for sa, sb in zip(a, b, strict=True) for x, y in zip(sa, sb, strict=True))
    assert not torch.equal(a[-1][2], c[-1][2])


def test_observation_shapes_and_timing():
    env = CoverageEnv(MISSION, 2, seed=0)
    obs = env.reset()
    n = MISSION.n_uavs
    assert obs.ego.shape == (2, n, 6) and obs.nbr_state.shape == (2, n, n, 6)
    assert obs.sense.shape == (2, n, SENSING_FEATURES) and obs.nbr_mask.shape == (2, n, n)
    assert not obs.nbr_mask[:, torch.arange(n), torch.arange(n)].any()
    assert env.global_state().shape == (2, env.global_state_dim())
    decisions = 0
    while not env.done:
        env.step(torch.zeros(2, n, 3))
        decisions += 1
    assert env.t == 200 and decisions == 67


def test_paoi_sawtooth_in_the_twin():
    env = CoverageEnv(MISSION.with_tup(5), 1, seed=0)
    env.reset()
    ages = []
    for _ in range(20):
        env.physics_step(torch.zeros(1, MISSION.n_uavs, 3))
        ages.append(float(env.observe().nbr_aoi[0, 0, 1]))
    assert ages == [1, 2, 3, 4, 1] * 4


def test_neighbour_beyond_comm_range_receives_nothing():
    far = dataclasses.replace(MISSION, launch=Launch(north_m=500, east_m=500, spacing_m=360.0), n_uavs=2)
    obs = CoverageEnv(far, 1, seed=0).reset()
    assert not obs.nbr_mask.any()
    near = dataclasses.replace(far, launch=Launch(north_m=500, east_m=500, spacing_m=300.0))
    assert CoverageEnv(near, 1, seed=0).reset().nbr_mask[0, 0, 1]


def test_launch_line_runs_along_its_bearing():
    from plmarl_sitl.twin.env import launch_positions

    n = 5
    offs = (torch.arange(n, dtype=torch.float64) - 2) * 30.0
    east_west = launch_positions(dataclasses.replace(MISSION, n_uavs=n, launch=Launch(400, 450, 30.0)), 20.0)
    # the default bearing (90) is the west-east line of every mission before the field, to the bit
    assert torch.equal(east_west[:, 0], torch.full((n,), 400.0, dtype=torch.float64))
    assert torch.equal(east_west[:, 1], 450.0 + offs) and torch.equal(east_west[:, 2], torch.full((n,), -20.0, dtype=torch.float64))
    north = launch_positions(dataclasses.replace(MISSION, n_uavs=n, launch=Launch(400, 450, 30.0, bearing_deg=0.0)), 20.0)
    assert torch.equal(north[:, 0], 400.0 + offs) and torch.equal(north[:, 1], torch.full((n,), 450.0, dtype=torch.float64))
    ne = launch_positions(dataclasses.replace(MISSION, n_uavs=n, launch=Launch(400, 450, 30.0, bearing_deg=45.0)), 20.0)
    step = ne[1:, :2] - ne[:-1, :2]
    assert torch.allclose(step, torch.tensor([30.0, 30.0], dtype=torch.float64) / 2**0.5)
    assert torch.allclose(ne[:, :2].mean(0), torch.tensor([400.0, 450.0], dtype=torch.float64))
    # the team plan's launch fit (what each agent computes from the states it heard) recovers a turned line
    from plmarl_sitl.model.service import launch_line

    heard = np.array([0, 2, 4])
    fit = launch_line(heard, ne[heard, :2].numpy(), n)
    assert np.abs(fit - ne[:, :2].numpy()).max() <= 0.005


def test_node_failure_removes_the_uav_and_switches_the_reward():
    m = dataclasses.replace(MISSION.with_tup(5), failures=(Failure(at_s=10, uav=2),))
    env = CoverageEnv(m, 1, seed=0)
    env.reset()
    flags = []
    while env.t < 30:
        obs, _, info = env.step(torch.zeros(1, m.n_uavs, 3))
        flags.append((env.t, bool(info.failed[0]), obs.nbr_mask[0, 0, 2].item(), obs.fail_flag[0, 0].item()))
    assert not env.alive[0, 2] and env.alive[0, [0, 1, 3]].all()
    assert all(failed == (t >= 10) for t, failed, _, _ in flags)
    # Silent from t = 10: missed at 10 and 15 (drop_after_missed = 2), dropped from t = 15.
    assert all(mask == (t < 15) for t, _, mask, _ in flags)
    assert all(f == (t >= 15) for t, _, _, f in flags)


def test_failure_curriculum_fails_the_requested_share():
    env = CoverageEnv(MISSION, 400, seed=0, failure_prob=0.2, failure_at_s=100.0)
    env.reset()
    planned = torch.isfinite(env.fail_at).any(-1).float().mean()
    assert 0.13 < float(planned) < 0.27


def test_greedy_is_high_and_heuristic_below_it():
    greedy = run_episodes(MISSION, lambda env: GreedyController(env), episodes=4, seed=3)
    heur = run_episodes(MISSION, lambda env: HeuristicController(env.mission), episodes=4, seed=3)
    assert greedy.coverage.mean() >= 0.9
    assert heur.coverage.mean() < greedy.coverage.mean() - 0.1
    assert greedy.min_separation.min() >= 2 * MISSION.radii.safe_m - 1.0


def _events_mission(*events):
    from plmarl_sitl.mission import Event

    return dataclasses.replace(MISSION.with_tup(5), events=tuple(Event(**e) for e in events))


def test_blackout_and_broker_outage_stop_deliveries_for_their_window():
    for ev in ({"type": "link_blackout", "at_s": 10, "duration_s": 10, "uavs": (1,)}, {"type": "broker_outage", "at_s": 10, "duration_s": 10}):
        env = CoverageEnv(_events_mission(ev), 1, seed=0)
        env.reset()
        t_rx = {}
        while env.t < 30:
            env.physics_step(torch.zeros(1, env.n, 3))
            t_rx[env.t] = env.holdings.t_rx[0].clone()
        assert float(t_rx[9][0, 1]) == 5.0 and float(t_rx[19][0, 1]) == 5.0 and float(t_rx[20][0, 1]) == 20.0
        other = float(t_rx[19][0, 2])
        assert other == (15.0 if ev["type"] == "link_blackout" else 5.0)


def test_tup_change_moves_the_signalling_instants():
    env = CoverageEnv(_events_mission({"type": "tup_change", "at_s": 12, "tup_s": 8}), 1, seed=0)
    env.reset()
    instants = set()
    while env.t < 40:
        env.physics_step(torch.zeros(1, env.n, 3))
        if float(env.holdings.t_rx[0, 0, 1]) == env.t:
            instants.add(env.t)
    assert instants == {5, 10, 16, 24, 32, 40}


def test_tup_change_counts_from_the_next_second_as_in_sitl():
    """T_up 15 -> 5 at t = 10: 10 is a multiple of the new interval, yet the change's own second
    follows the old one, as the SITL world and agent do (LockstepPacer._instant_tup,
    tests/deploy/test_clock.py), so the instants are 0, 15, 20, 25."""
    m = _events_mission({"type": "tup_change", "at_s": 10, "tup_s": 5}).with_tup(15)
    env = CoverageEnv(m, 1, seed=0)
    env.reset()
    instants = {0}
    while env.t < 26:
        env.physics_step(torch.zeros(1, env.n, 3))
        if float(env.holdings.t_rx[0, 0, 1]) == env.t:
            instants.add(env.t)
    assert instants == {0, 15, 20, 25}


def test_gnss_noise_perturbs_reported_positions_only():
    env = CoverageEnv(_events_mission({"type": "gnss_noise", "at_s": 0, "std_m": 5.0, "uavs": (0,)}), 1, seed=0)
    obs = env.reset()
    err = (obs.ego[0, :, :3] - env.pos[0]).abs().sum(-1)
    assert err[0] > 0 and torch.all(err[1:] == 0)
