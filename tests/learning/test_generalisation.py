"""Issue 12: inputs the policy cannot memorise, sizes independent of N / M / clusters, the
predicted-in-range failure flag, the training distribution, and a tiny training run."""

from __future__ import annotations

import math
from typing import Optional

import numpy as np
import pytest
import torch

from plmarl_sitl.learning.eval.controllers import LearnedController
from plmarl_sitl.learning.nn import Actor, BeliefTracker, DeployedPolicy, FeatureScales, make_predictor
from plmarl_sitl.learning.nn.belief import FailureFlags
from plmarl_sitl.learning.nn.contract import PolicyInputs
from plmarl_sitl.learning.nn.features import DEMAND_FEATURES, EGO_FEATURES, TOKEN_FEATURES, policy_input
from plmarl_sitl.learning.nn.io import script
from plmarl_sitl.learning.train.mappo import Args, train
from plmarl_sitl.learning.train.scenarios import training_mission
from plmarl_sitl.mission import load_mission
from plmarl_sitl.twin.env import CoverageEnv, launch_positions

MISSION = load_mission("missions/paper_urban.yaml")


def _policy(seed: int = 0, reads_map: bool = True) -> DeployedPolicy:
    torch.manual_seed(seed)
    actor = Actor(reads_map=reads_map)
    for p in actor.parameters():  # non-trivial actions
        torch.nn.init.normal_(p, std=0.3)
    return DeployedPolicy(actor, *FeatureScales.from_mission(MISSION)).eval()


def _scenario(gen: torch.Generator, m: int, k: int) -> tuple[torch.Tensor, ...]:
    ego = torch.cat([torch.tensor([400.0, 450.0, -90.0]), torch.randn(3, generator=gen) * 5])
    bel = torch.cat([ego[:3] + torch.randn(m, 3, generator=gen) * torch.tensor([200.0, 200.0, 10.0]),
                     torch.randn(m, 3, generator=gen) * 5], -1)
    mask = torch.rand(m, generator=gen) < 0.7
    sense = torch.rand(4, generator=gen)
    demand = torch.cat([ego[:2] + (torch.rand(k, 2, generator=gen) - 0.5) * 1200.0, torch.randint(0, 40, (k, 1), generator=gen).float()], -1)
    return ego, bel, mask, sense, demand


@pytest.mark.parametrize("reads_map", [True, False], ids=["map", "map-blind"])
def test_a_translated_scenario_gives_the_same_actions(reads_map: bool):
    """As exported (the fused file): without a plan (the reference path) and with one (the fast path)."""
    from plmarl_sitl.learning.nn.fused import fuse_policy
    from plmarl_sitl.learning.nn.io import POLICY_ATTRS, freeze

    gen = torch.Generator().manual_seed(1)
    pol = freeze(fuse_policy(_policy(reads_map=reads_map)), POLICY_ATTRS)
    for shift in ([300.0, -200.0], [-1234.5, 5000.0], [0.25, 0.5]):
        ego, bel, mask, sense, demand = _scenario(gen, 5, 30)
        target = ego[:2] + torch.tensor([180.0, -60.0])
        d3 = torch.tensor(shift + [0.0])
        moved = (ego + torch.cat([d3, torch.zeros(3)]), bel + torch.cat([d3, torch.zeros(3)]), mask, sense,
                 demand + torch.tensor(shift + [0.0]))
        for plan, moved_plan in ((None, None), (target, target + torch.tensor(shift))):
            want = pol(ego, bel, mask, sense, torch.tensor(True), demand, plan)
            got = pol(moved[0], moved[1], mask, sense, torch.tensor(True), moved[4], moved_plan)
            assert torch.allclose(want, got, atol=1e-4), (shift, want, got)


def test_input_size_does_not_depend_on_neighbours_clusters_or_cells():
    gen = torch.Generator().manual_seed(2)
    scales = FeatureScales.from_mission(MISSION)
    pol = script(_policy())
    for m, k in ((0, 1), (1, 5), (7, 100), (19, 400)):
        ego, bel, mask, sense, demand = _scenario(gen, m, k)
        ego_x, nbr_x, rel_x, _, tok_x, tok_m = policy_input(scales, PolicyInputs(ego, bel, mask, sense, torch.tensor(False), demand))
        assert ego_x.shape == (EGO_FEATURES,) and nbr_x.shape == (m, 6) and rel_x.shape == (m, 3)
        assert tok_x.shape == (k, TOKEN_FEATURES) and tok_m.shape == (k,)
        assert torch.isfinite(pol(ego, bel, mask, sense, torch.tensor(False), demand)).all()
    # Empty cells and cell order change nothing: a message may carry only the nonzero cells.
    ego, bel, mask, sense, demand = _scenario(gen, 4, 50)
    padded = torch.cat([demand, torch.tensor([[0.0, 0.0, 0.0], [9e3, 9e3, 0.0]])])[torch.randperm(52, generator=gen)]
    a, b = (policy_input(scales, PolicyInputs(ego, bel, mask, sense, torch.tensor(False), d))[0] for d in (demand, padded))
    assert torch.allclose(a, b)
    assert torch.allclose(*(pol(ego, bel, mask, sense, torch.tensor(False), d) for d in (demand, padded)), atol=1e-6)
    # No map yet (demand None) is the empty map.
    assert torch.equal(pol(ego, bel, mask, sense, torch.tensor(False)),
                       pol(ego, bel, mask, sense, torch.tensor(False), torch.zeros(1, 3)))


def test_cells_near_a_believed_neighbour_are_claimed():
    scales = FeatureScales.from_mission(MISSION)
    ego = torch.tensor([500.0, 500.0, -90.0, 0.0, 0.0, 0.0])
    demand = torch.tensor([[800.0, 500.0, 60.0]])  # 300 m north: ring 300-600 (ring 2), octant 0
    far_nbr = torch.tensor([[500.0, 900.0, -90.0, 0.0, 0.0, 0.0]])
    near_nbr = torch.tensor([[780.0, 510.0, -90.0, 0.0, 0.0, 0.0]])
    on = torch.tensor([True])
    def desc(nbr: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        return policy_input(scales, PolicyInputs(ego, nbr, mask, torch.zeros(4), torch.tensor(False), demand))[0][-DEMAND_FEATURES:]
    total, free = desc(far_nbr, on).chunk(2)
    assert float(total.sum()) > 0 and torch.equal(total, free)
    total, free = desc(near_nbr, on).chunk(2)
    assert float(total.sum()) > 0 and float(free.sum()) == 0.0
    total, free = desc(near_nbr, ~on).chunk(2)  # a masked slot claims nothing
    assert torch.equal(total, free)


def test_demand_tokens_say_which_cells_are_nearer_to_a_neighbour():
    scales = FeatureScales.from_mission(MISSION)
    ego = torch.tensor([500.0, 500.0, -90.0, 0.0, 0.0, 0.0])
    demand = torch.tensor([[800.0, 500.0, 60.0], [200.0, 500.0, 30.0], [0.0, 0.0, 0.0]])
    nbr = torch.tensor([[850.0, 500.0, -90.0, 0.0, 0.0, 0.0]])  # 50 m from cell 0, 650 m from cell 1
    on = torch.tensor([True])
    *_, tok, tok_m = policy_input(scales, PolicyInputs(ego, nbr, on, torch.zeros(4), torch.tensor(False), demand))
    assert tok_m.tolist() == [True, True, False]
    r = scales.r_comm
    assert torch.allclose(tok[0], torch.tensor([300.0 / r, 0.0, math.log1p(1.0), (50.0 - 300.0) / r, math.log1p(1.0)]))
    assert torch.allclose(tok[1, 3:], torch.tensor([(650.0 - 300.0) / r, 0.0]))
    *_, tok, _ = policy_input(scales, PolicyInputs(ego, nbr, ~on, torch.zeros(4), torch.tensor(False), demand))
    assert tok[0, 3] == 2.0 and tok[0, 4] == 0.0  # a masked slot is nobody


def test_failure_flags_latch_only_for_a_neighbour_predicted_in_range():
    flags = FailureFlags(350.0)
    ego = torch.tensor([[0.0, 0.0, -100.0, 0, 0, 0], [0.0, 0.0, -100.0, 0, 0, 0]])
    bel = torch.tensor([[[0.0, 0.0, 0, 0, 0, 0], [600.0, 0.0, -100.0, 0, 0, 0]],
                        [[0.0, 0.0, 0, 0, 0, 0], [100.0, 0.0, -100.0, 0, 0, 0]]])
    alive = torch.tensor([True, True])
    had = torch.tensor([[False, True], [False, True]])
    assert flags.update(had, bel, ego, alive).tolist() == [False, False]
    gone = torch.zeros(2, 2, dtype=torch.bool)
    assert flags.update(gone, bel, ego, alive).tolist() == [False, True]  # 0 flew away, 1 went silent nearby
    assert flags.update(gone, bel * 0 + 1e4, ego, alive).tolist() == [False, True]  # latched
    assert flags.update(gone, bel, ego, torch.tensor([True, False])).tolist() == [False, False]  # dead agents: no f
    flags.reset()
    assert flags.update(gone, bel, ego, alive).tolist() == [False, False]


def test_training_scenarios_vary_n_and_clusters_and_launch_lines():
    rng = np.random.default_rng(0)
    seen = set()
    for i in range(12):
        m = training_mission(MISSION, rng)
        assert 3 <= m.n_uavs <= 8 and 2 <= m.users.n_clusters <= 8 and m.users.mobility == "mixed"
        seen.add((m.n_uavs, m.users.n_clusters))
        env = CoverageEnv(m, 3, i, random_launch=True)
        obs = env.reset()
        assert obs.ego.shape == (3, m.n_uavs, 6) and obs.demand.shape == (3, 400, 3)  # 50 m cells on 1 km^2
        assert float(obs.demand[..., 2].sum()) == 3 * m.users.count
        p = obs.ego[..., :2]
        assert (p >= 0).all() and (p[..., 0] <= 1000).all() and (p[..., 1] <= 1000).all()
        gaps = (p[:, 1:] - p[:, :-1]).norm(dim=-1)
        assert torch.allclose(gaps, torch.full_like(gaps, m.launch.spacing_m), atol=1e-3)  # a line at the mission's spacing
        assert not torch.allclose(p[0], p[1])  # each environment its own line
    assert len(seen) >= 4
    # Randomisation off: the mission's launch line in every environment.
    env = CoverageEnv(MISSION, 2, 0)
    want = launch_positions(MISSION, float(-env.pos[0, 0, 2]))[:, :2].float()
    assert torch.allclose(env.pos[..., :2], want.expand(2, -1, -1))


def test_the_demand_map_is_refreshed_at_its_period_only():
    env = CoverageEnv(MISSION, 2, 0)
    first = env.observe().demand
    while env.t < 27:
        env.step(torch.zeros(2, 4, 3))
    assert torch.equal(env.observe().demand, first)
    env.step(torch.zeros(2, 4, 3))  # t = 30
    assert env.t == 30 and not torch.equal(env.observe().demand, first)


def test_learned_controller_runs_on_any_swarm_size():
    tracker = script(BeliefTracker(make_predictor("cv"), 10, 1.0))
    pol = script(_policy())
    for n, count in ((3, 120), (8, 480)):
        m = MISSION.__class__(**{**MISSION.__dict__, "n_uavs": n,
                                 "users": MISSION.users.__class__(**{**MISSION.users.__dict__, "count": count, "layout": "lattice",
                                                                     "cluster_centers": ()})})
        env = CoverageEnv(m, 2, 0)
        ctl = LearnedController(tracker, pol, m)
        ctl.reset()
        obs = env.observe()
        for _ in range(5):
            obs, _, _ = env.step(ctl.act(obs))
        assert obs.ego.shape == (2, n, 6)


def test_tiny_training_run_on_the_scenario_distribution(tmp_path):
    res = train(Args(method="tag-mappo", episodes=8, num_envs=4, imitation_rounds=1, imitation_episodes_per_round=4,
                     imitation_tup_chunks=2, critic_warmup_iters=0, out=str(tmp_path / "mappo")))
    assert res["episodes"] == 8 and np.isfinite(res["last"]["losses/value_loss"])
    assert 3 <= res["last"]["charts/n_uavs"] <= 8


def test_plan_input_is_relative_and_absent_before_a_plan():
    """The team-plan features are the offset to the target: a translated agent and target
    give the same input; without a target they are zero (and say so)."""
    scales = FeatureScales.from_mission(MISSION)
    gen = torch.Generator().manual_seed(3)
    ego, bel, mask, sense, demand = _scenario(gen, 3, 5)
    fail = torch.tensor(False)
    target = ego[:2] + torch.tensor([120.0, -40.0])
    shift = torch.tensor([37.0, -210.0])
    sh3 = torch.cat([shift, torch.zeros(1)])
    a = policy_input(scales, PolicyInputs(ego, bel, mask, sense, fail, demand, target))[0]
    b = policy_input(scales, PolicyInputs(ego + torch.cat([sh3, torch.zeros(3)]), bel + torch.cat([sh3, torch.zeros(3)]), mask, sense,
                                          fail, demand + torch.cat([shift, torch.zeros(1)]), target + shift))[0]
    assert torch.allclose(a, b, atol=1e-5)
    none = policy_input(scales, PolicyInputs(ego, bel, mask, sense, fail, demand))[0]
    assert torch.equal(none[-5:], torch.zeros(5)) and a[-1] == 1.0


class _SixInputs(torch.nn.Module):
    """A version-2 file of before the team plan (no `takes_plan`): six inputs, no target."""

    def __init__(self, inner: DeployedPolicy) -> None:
        super().__init__()
        self.inner = inner
        self.r_comm = inner.r_comm
        self.input_version = 2

    def forward(self, ego: torch.Tensor, beliefs: torch.Tensor, mask: torch.Tensor, sense: torch.Tensor,
                fail_flag: torch.Tensor, demand: Optional[torch.Tensor] = None) -> torch.Tensor:  # noqa: UP045
        return self.inner(ego, beliefs, mask, sense, fail_flag, demand, None)


def test_a_version_2_policy_without_the_plan_runs_with_six_inputs():
    """Version-2 files exported before the team plan take six inputs: the twin calls them without it."""
    from plmarl_sitl.learning.nn.contract import PolicyForm

    policy = script(_SixInputs(DeployedPolicy(Actor(), *FeatureScales.from_mission(MISSION))))
    assert PolicyForm.of(policy) == PolicyForm(2, False, True) and PolicyForm.of(policy).arity == 6
    tracker = BeliefTracker(make_predictor("hold"), MISSION.signalling.buffer_len, MISSION.timing.dt_s)
    ctl = LearnedController(tracker, policy, MISSION)
    assert ctl.perceive.plan is None
    env = CoverageEnv(MISSION, 2, 0)
    ctl.reset()
    obs = env.observe()
    for _ in range(3):
        obs, _, _ = env.step(ctl.act(obs))
