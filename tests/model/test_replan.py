"""Re-planning at failures (issue 24): the gossip of the failed set and epoch
(model/gossip.py), the plan-aware prediction (model/plan_motion.py) and the re-plan of
`TeamPlans` reached by every survivor alike, in the twin, with no leader."""

from __future__ import annotations

import numpy as np
import torch

from plmarl_sitl.bench.replan import live_declared
from plmarl_sitl.learning.eval.controllers import ServiceController
from plmarl_sitl.mission import load_mission
from plmarl_sitl.model.gossip import (
    HEARD_MARGIN_DB,
    HEARD_RANGE_M,
    SUSPECT_MARGIN_DB,
    Gossip,
    clear_hearing,
    heard,
    key_of,
    rank_of,
    since_of,
)
from plmarl_sitl.twin.env import CoverageEnv


def test_the_merge_is_a_max_of_ranks_whatever_the_order() -> None:
    """Per identity: a newer incarnation beats a declaration of an older one, at one
    incarnation failed beats alive, and of two declarations the earlier instant wins."""
    key = torch.tensor([1, 0, 1, 2])
    since = torch.tensor([30, 0, 60, 0])
    other_key = torch.tensor([1, 1, 2, 1])
    other_since = torch.tensor([45, 45, 0, 90])
    a, b = rank_of(key, since), rank_of(other_key, other_since)
    ab, ba = torch.maximum(a, b), torch.maximum(b, a)
    assert torch.equal(ab, ba) and torch.equal(torch.maximum(ab, a), ab)  # commutative, idempotent
    assert key_of(ab).tolist() == [1, 1, 2, 2] and since_of(ab).tolist() == [30, 45, 0, 0]


def test_gossip_crosses_a_line_one_hop_per_instant() -> None:
    """Agents 0-1-2-3 in a line, each hearing only its neighbours, and a silent identity 4:
    agent 0's declaration of 4 reaches agent 3, which never hears agent 0, three instants
    later; nobody learns anything it was not sent."""
    n = 5
    g = Gossip(1, n)
    hears = torch.zeros(1, n, n, dtype=torch.bool)
    for i in range(n - 2):
        hears[0, i, i + 1] = hears[0, i + 1, i] = True
    mine = torch.zeros(1, n, n, dtype=torch.bool)
    mine[0, 0, 4] = True  # agent 0 declares identity 4 (knowledge only; the rule is elsewhere)
    g.declare(mine, torch.tensor([[60, 0, 0, 0, 0]]))
    known = []
    for _ in range(3):
        g.receive(hears)
        known.append(g.failed[0, :4, 4].tolist())
    assert known == [[True, True, False, False], [True, True, True, False], [True, True, True, True]]
    assert g.epoch[0, :4].tolist() == [60, 60, 60, 60]
    assert not g.failed[0, :, :4].any()


def run(mission_path: str, replan: bool, seed: int = 1_000_000_123, batch: int = 4):
    m = load_mission(mission_path).with_tup(15)
    env = CoverageEnv(m, batch, seed)
    ctl = ServiceController(m, replan=replan)
    ctl.reset()
    obs = env.observe()
    cover = []
    while not env.done:
        obs, _, info = env.step(ctl.act(obs))
        cover.append(info.coverage)
    return env, ctl, torch.cat(cover, -1)


def test_survivors_agree_on_the_re_plan_and_cover_more() -> None:
    """failure_2of6: UAVs 1 and 4 of six fail at t = 100 s. At the end every survivor's copy
    of the plan holds only true failures, one epoch, and exactly the same points and slots
    as every other survivor's, though some learnt it from their own misses and others only
    from gossip; most episodes know both failures (a UAV at the edge of everyone's hearing
    is not declared: no one predicts it in clear hearing); and the swarm covers more after
    the failure than without re-plans."""
    env, ctl, cov = run("missions/suite/failure_2of6_a.yaml", replan=True)
    plans = ctl.targets.plans
    both = 0
    for b in range(env.num_envs):
        alive = np.flatnonzero(env.alive[b].numpy())
        assert alive.tolist() == [0, 2, 3, 5]
        ref = alive[0]
        for a in alive:
            assert not plans.failed[b, a, alive].any()  # no live teammate declared
            assert np.array_equal(plans.failed[b, a], plans.failed[b, ref])
            assert plans.epoch[b, a] == plans.epoch[b, ref] > 100
            assert np.array_equal(plans.slot[b, a], plans.slot[b, ref])
            assert np.array_equal(np.isnan(plans.points[b, a]), np.isnan(plans.points[b, ref]))
            assert np.array_equal(np.nan_to_num(plans.points[b, a]), np.nan_to_num(plans.points[b, ref]))
        own = plans.slot[b, ref, alive]
        assert len(set(own.tolist())) == len(alive)  # one point each
        both += plans.failed[b, ref].tolist() == [False, True, False, False, True, False]
    assert both >= 3, both
    _, _, fixed = run("missions/suite/failure_2of6_a.yaml", replan=False)
    after = slice(150, None)
    assert float(cov[:, after].mean()) > float(fixed[:, after].mean()) + 0.03


def test_no_failure_is_declared_where_none_happened() -> None:
    """Links fail inside R_comm under interference (two UAVs on a cluster), the prediction
    is metres off in transit, and a broker outage silences everyone for two instants:
    none of them may declare a live teammate failed (a receiver that hears no one at an
    instant declares nothing)."""
    for path in ("missions/paper_urban.yaml", "missions/suite/diffuse_failure.yaml", "missions/suite/n8.yaml",
                 "missions/broker_outage.yaml"):
        env, ctl, _ = run(path, replan=True, batch=3)
        assert not env.gossip.failed.any(), path
        assert ctl.targets.replans_done == 0, path


def test_a_re_plan_depends_on_what_is_known_not_on_the_order_it_was_learnt() -> None:
    """Two copies of a 4-UAV plan: one learns UAV 1's failure at instant 60, flies that
    interim plan to second 90, then learns UAV 2's (same epoch) too; the other learns both
    at second 90 only. Both end with the same points, slots and predicted positions (the
    prediction is re-flown from the epoch)."""
    from plmarl_sitl.model.plan_motion import PlanMotion
    from plmarl_sitl.model.service import ServiceGrid, TeamPlans
    from plmarl_sitl.model.vehicle import Limits

    grid = ServiceGrid(1000.0, 1000.0, 100.0, 100.0, 350.0, 20.0)
    counts = np.zeros(100)
    for cell in (33, 35, 55, 53):
        counts[cell] = 60
    plans = TeamPlans(grid, 4, PlanMotion(Limits(20.0, 5.0, 30.0, 150.0), 100.0, 30.0, 3, lambda t: t % 15 == 0))
    line = np.stack([np.full(4, 500.0), 440.0 + 40.0 * np.arange(4)], -1)
    plans.start(np.stack([line, line])[None], counts[None])
    plans.motion.advance(60, plans.all_targets())
    plans.replan(0, 0, np.array([False, True, False, False]), 60)  # copy 0 learns of UAV 1 at 60
    plans.motion.advance(90, plans.all_targets())
    both = np.array([False, True, True, False])
    plans.replan(0, 0, both, 60)
    plans.replan(0, 1, both, 60)  # copy 1 learns both at 90
    assert np.array_equal(plans.slot[0, 0], plans.slot[0, 1]) and plans.slot[0, 0, 1] == plans.slot[0, 0, 2] == -1
    assert np.array_equal(np.nan_to_num(plans.points[0, 0]), np.nan_to_num(plans.points[0, 1]))
    assert torch.allclose(plans.motion.state[0, 0, [0, 3]], plans.motion.state[0, 1, [0, 3]])


def test_a_steady_link_heard_before_and_missed_now_is_evidence_of_a_failure() -> None:
    """`steady`: receiver 0 heard teammate 1 at the previous instant; where the prediction
    keeps both where they were, the link is steady (a live teammate would be heard again:
    the channel is a function of the positions); where teammate 1 moved 50 m, where it sits
    10 m inside R_comm, or where it was not heard before, it is not."""
    from plmarl_sitl.model.gossip import STEADY_RANGE_M, steady

    ch = load_mission("missions/paper_urban.yaml").channel
    comm = 350.0

    def pred(*xs: float) -> torch.Tensor:  # (1, 1, n, 3): identities on a line at 100 m altitude
        return torch.tensor([[[[0.0, x, -100.0] for x in xs]]], dtype=torch.float64)

    me = torch.tensor([0])
    heard = torch.tensor([[[False, True, True]]])
    still = steady(heard, pred(0.0, 300.0, -200.0), pred(0.0, 300.0, -200.0), me, ch, comm)
    assert still.tolist() == [[[False, True, True]]]
    moved = steady(heard, pred(0.0, 350.0 - STEADY_RANGE_M + 5.0, -150.0), pred(0.0, 300.0, -200.0), me, ch, comm)
    assert moved.tolist() == [[[False, False, False]]]  # 1: too close to R_comm and moved; 2: moved 50 m
    edge = steady(heard, pred(0.0, 340.0, -200.0), pred(0.0, 340.0, -200.0), me, ch, comm)
    assert edge.tolist() == [[[False, False, True]]]
    unheard = steady(torch.tensor([[[False, False, True]]]), pred(0.0, 300.0, -200.0), pred(0.0, 300.0, -200.0), me, ch, comm)
    assert unheard.tolist() == [[[False, False, True]]]


def test_a_link_heard_before_and_predicted_clear_enough_is_evidence_however_far_it_moved() -> None:
    """`heard`: a teammate heard at the previous instant whose link the prediction at the missed
    instant keeps HEARD_RANGE_M inside R_comm and HEARD_MARGIN_DB above the threshold, wherever it
    came from; the teammate at 220 m with a UAV 130 m behind the receiver (5.4 dB) is not in clear
    hearing (6 dB), so before session 26 its silence was no evidence."""
    ch = load_mission("missions/paper_urban.yaml").channel
    comm = 350.0
    me = torch.tensor([0])

    def pred(*xs: float) -> torch.Tensor:  # (1, 1, n, 3): identities on a line at 100 m altitude
        return torch.tensor([[[[0.0, x, -100.0] for x in xs]]], dtype=torch.float64)

    heard_prev = torch.tensor([[[False, True, True]]])
    near = pred(0.0, 220.0, -130.0)  # 1: 5.4 dB above the threshold
    assert heard(heard_prev, near, me, ch, comm).tolist() == [[[False, True, True]]]
    assert clear_hearing(near, me, near[:, :, 0], ch, comm).tolist() == [[[False, False, True]]]
    assert heard(heard_prev, pred(0.0, 240.0, -100.0), me, ch, comm).tolist() == [[[False, False, True]]]  # 1: 2.4 dB
    edge = pred(0.0, comm - HEARD_RANGE_M + 10.0, -200.0)  # 1: 5.2 dB, but 10 m from R_comm
    assert heard(heard_prev, edge, me, ch, comm).tolist() == [[[False, False, True]]]
    assert heard(torch.tensor([[[False, False, True]]]), near, me, ch, comm).tolist() == [[[False, False, True]]]
    assert HEARD_MARGIN_DB < SUSPECT_MARGIN_DB


def test_a_failure_is_declared_at_the_first_missed_instant_and_known_soon_after() -> None:
    """failure_2of6_a: UAVs 1 and 4 fail at t = 100 s. At T_up 15 the first instant they miss
    is 105, at T_up 50 it is 100 itself (seen at the decision of 102). Some survivor declares
    each at that decision (by clear hearing, or on a link heard at the instant before that the
    prediction keeps steady): every one at T_up 15, all but one at T_up 50; every survivor
    knows a declared failure within two more instants, most within one (gossip hops). Session 12 needed two missed instants (120
    at T_up 15) and some failures were never declared. No live UAV is declared."""
    for tup, instant, first in ((15, 105, 105), (50, 100, 102)):
        # The counts below are of the greedy placement's geometry (who hears whom at 50 and 105 s);
        # under `placement: search` (the default since session 15) one of the 8 failures at T_up 15
        # is not declared by 135 s on these episodes (docs/RESULTS.md, Session 15 at a glance).
        m = load_mission("missions/suite/failure_2of6_a.yaml").with_tup(tup).with_placement("greedy")
        env = CoverageEnv(m, 4, 1_000_000_123)
        ctl = ServiceController(m)
        ctl.reset()
        obs = env.observe()
        some = torch.full((4, 6), -1)  # decision at which some survivor first knew j failed
        all_ = torch.full((4, 6), -1)  # the decision before the step after which every survivor knew it
        while obs.t < instant + 2 * tup:
            t = obs.t  # the twin steps one decision (3 s) at a time
            obs, _, _ = env.step(ctl.act(obs))
            live = env.alive
            knows = env.gossip.failed & live.unsqueeze(-1)  # [b, i, j] live i knows j failed
            some = torch.where((some < 0) & knows.any(1), t, some)
            everyone = (knows | ~live.unsqueeze(-1)).all(1)
            all_ = torch.where((all_ < 0) & everyone & ~live, t, all_)
        dead = [1, 4]
        assert not (env.gossip.failed & env.alive.unsqueeze(-1) & env.alive.unsqueeze(-2)).any()
        declared = some[:, dead] >= 100
        # at T_up 50 the instant before the failure (50 s) can find the swarm still settling, so a
        # pair dying together is not on a steady link: 1 of these 8 failures goes undeclared
        assert int(declared.sum()) >= (8 if tup == 15 else 7), (tup, some)
        assert (some[:, dead][declared] <= first).all(), (tup, some)  # declared at the first missed instant
        assert (all_[:, dead][declared] >= 100).all(), (tup, all_)  # then known by all within two instants
        if tup == 15:
            assert int((all_[:, dead] < instant + tup).sum()) >= 6, (tup, all_)  # most by the next one


def test_a_false_declaration_is_a_live_uav_held_failed_by_a_live_copy() -> None:
    """`bench.replan` counts false declarations over the whole episode with this: a live UAV
    declared by a live copy counts; a dead UAV's declaration, or one only a dead copy holds, does not."""
    g = Gossip(1, 4)
    alive = torch.tensor([[True, True, True, False]])
    assert not live_declared(g.failed, alive).any()
    failed = torch.zeros(1, 4, 4, dtype=torch.bool)
    failed[0, 0, 3] = True  # a true declaration (3 is dead)
    failed[0, 3, 1] = True  # held only by the dead copy 3
    g.declare(failed, torch.tensor([[50, 0, 0, 50]]))
    assert live_declared(g.failed, alive).tolist() == [[False, False, False, False]]
    failed[0, 1, 2] = True  # live copy 1 holds live UAV 2 failed
    g.declare(failed, torch.tensor([[50, 100, 0, 50]]))
    assert live_declared(g.failed, alive).tolist() == [[False, False, True, False]]
