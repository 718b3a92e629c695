"""Un-declaring a live teammate (issue 24, schema 4): a declared UAV heard again, directly
or by gossip of a newer incarnation, is taken back by everyone (model/gossip.py); the twin's
batched `Gossip` and one deployed agent's `Knowledge`, fed the real wire's messages, hold the
same knowledge; a copy of the plan that acted on the false declaration rolls back to the
plan of one that never heard it (model/service.py)."""

from __future__ import annotations

import random

import numpy as np
import torch

from plmarl_sitl.deploy.mqtt.schema import StateMsg, decode_state, encode_state
from plmarl_sitl.learning.eval.controllers import ServiceController
from plmarl_sitl.mission import load_mission
from plmarl_sitl.model.gossip import Gossip, may_predict, rank_of
from plmarl_sitl.model.knowledge import Knowledge, Known
from plmarl_sitl.twin.env import CoverageEnv


def line(n: int, upto: int) -> torch.Tensor:
    """(1, n, n) hearing of agents 0..upto-1 in a line, each hearing its neighbours."""
    hears = torch.zeros(1, n, n, dtype=torch.bool)
    for i in range(upto - 1):
        hears[0, i, i + 1] = hears[0, i + 1, i] = True
    return hears


def test_a_declared_uav_heard_again_is_taken_back_by_everyone() -> None:
    """Line 0-1-2-3; agent 0 falsely declares 3 (which 0 does not hear) at instant 60. Agent 2
    learns it at the second instant and hears 3 then: it takes 3 back at once (incarnation
    1); the newer incarnation then beats the declaration everywhere, one hop per instant."""
    n = 4
    g = Gossip(1, n)
    mine = torch.zeros(1, n, n, dtype=torch.bool)
    mine[0, 0, 3] = True
    g.declare(mine, torch.tensor([[60, 0, 0, 0]]))
    keys = []
    for _ in range(4):
        g.receive(line(n, n))
        keys.append(g.key[0, :, 3].tolist())
    assert keys == [[1, 1, 0, 0],  # 1 learns the declaration from 0
                    [1, 1, 2, 0],  # 2 learns it and hears 3 at once: takes it back (3 heard 2's older state)
                    [1, 2, 2, 2],  # incarnation 1 reaches 1 and 3
                    [2, 2, 2, 2]]  # and 0
    assert not g.failed.any()
    assert g.epoch[0].tolist() == [0] * 4  # no declaration left: every copy's plan is the one without re-plans
    for _ in range(2):
        g.receive(line(n, n))
    assert g.key[0, :, 3].tolist() == [2] * 4  # converged, no leader


def test_the_declared_uav_takes_itself_back_when_it_hears_of_it() -> None:
    """3 is declared by 0 and 1, which 3 hears but which do not hear 3 (a one-way link): 3
    learns the declaration, bumps its incarnation, and its next state takes it back."""
    n = 4
    g = Gossip(1, n)
    mine = torch.zeros(1, n, n, dtype=torch.bool)
    mine[0, 0, 3] = mine[0, 1, 3] = True
    g.declare(mine, torch.tensor([[30, 30, 0, 0]]))
    hears = torch.zeros(1, n, n, dtype=torch.bool)
    hears[0, 3, 0] = True  # 3 hears 0 only
    g.receive(hears)
    assert g.key[0, 3, 3] == 2  # itself: incarnation 1
    assert g.failed[0, 0, 3] and g.failed[0, 1, 3]
    hears[0, 0, 3] = hears[0, 1, 3] = True  # now 0 and 1 hear 3 (3's message carries incarnation 1)
    g.receive(hears)
    assert not g.failed.any() and g.key[0, :, 3].tolist() == [2, 2, 0, 2]


def test_a_dead_uav_stays_declared_and_a_new_declaration_of_a_newer_incarnation_wins() -> None:
    """A refutation needs a message of the identity (or of someone who heard one): a dead UAV
    is never taken back. Declared again at incarnation 1, it is failed again everywhere."""
    n = 3
    g = Gossip(1, n)
    g.rank[0, :, 2] = rank_of(torch.tensor(2), torch.tensor(0))  # everyone: identity 2 alive at incarnation 1
    mine = torch.zeros(1, n, n, dtype=torch.bool)
    mine[0, 0, 2] = True
    g.declare(mine, torch.tensor([[90, 0, 0]]))
    assert g.key[0, 0, 2] == 3 and g.since[0, 0, 2] == 90
    for _ in range(2):
        g.receive(line(n, 2))  # 2 is dead: heard by nobody
    assert g.failed[0, :2, 2].all() and g.epoch[0, :2].tolist() == [90, 90]


def test_may_predict_needs_the_same_declarations_before_the_missed_instant() -> None:
    """A plan is a function of the declarations (identity, instant): the receiver predicts a
    sender by its own plan only if the sender's last message knew the same declarations
    before the newest instant (a declaration since then has not yet changed the prediction)."""
    def rank(decl: dict[int, int], inc: dict[int, int] | None = None) -> torch.Tensor:
        key = torch.tensor([2 * (inc or {}).get(j, 0) + (j in decl) for j in range(4)])
        return rank_of(key, torch.tensor([decl.get(j, 0) for j in range(4)]))

    mine = rank({}, {3: 1})  # the receiver took 3 back (its copy rolled back to the plan without it)
    heard = torch.stack([rank({3: 60}), rank({}), rank({1: 90}), rank({1: 60})]).unsqueeze(0)
    assert may_predict(heard, mine.unsqueeze(0), 90).tolist() == [[False, True, True, False]]
    assert Known({}, {3: 1}).predicts_alike(Known({}), 90) and not Known({}, {3: 1}).predicts_alike(Known({3: 60}), 90)
    assert Known({1: 90}).predicts_alike(Known({}), 90) and not Known({1: 60}).predicts_alike(Known({}), 90)


def wire(known: Known, sender: int, t: int) -> Known:
    """The knowledge as a receiver decodes it from the sender's state message of instant t."""
    raw = encode_state(StateMsg.with_knowledge(sender, 1, t, t * 1000, (0.0,) * 6, known))
    assert len(raw) == 39 + 7 * len(set(known.failed) | set(known.inc))
    return decode_state(raw).known()


def test_the_agents_knowledge_from_real_messages_equals_the_twins() -> None:
    """Random hearing graphs at 40 instants and random declarations between them: each
    agent's `Knowledge`, fed the decoded state messages of the others (what each knew before
    the instant), holds at every instant exactly the twin `Gossip`'s row (keys and epoch)."""
    rng = random.Random(24)
    n, tup = 6, 15
    g = Gossip(1, n)
    agents = [Knowledge(i) for i in range(n)]
    bumps = 0
    for step in range(1, 41):
        t = step * tup
        hears = torch.tensor([[rng.random() < 0.5 and i != j for j in range(n)] for i in range(n)]).unsqueeze(0)
        sent = [a.view(before=t) for a in agents]
        for i, a in enumerate(agents):
            for j in range(n):
                if hears[0, i, j]:
                    a.learn(t, wire(sent[j], j, t), j)
        g.receive(hears)
        d = t + 3  # a decision between instants: declare a random teammate not heard at t
        mine = torch.zeros(1, n, n, dtype=torch.bool)
        for i, a in enumerate(agents):
            if rng.random() < 0.3:
                j = rng.choice([j for j in range(n) if j != i and not hears[0, i, j]] or [None])
                if j is not None and j not in a.view(before=d + 1).failed:
                    mine[0, i, j] = True
                    a.learn(d, a.view(before=d + 1).declared([j], t))
        g.declare(mine, torch.where(mine.any(-1), torch.full((1, n), t), torch.zeros(1, n, dtype=torch.int64)))
        for i, a in enumerate(agents):
            v = a.view(before=d + 1)
            assert [v.key(j) for j in range(n)] == g.key[0, i].tolist(), (t, i)
            assert [v.failed.get(j, 0) for j in range(n)] == g.since[0, i].tolist(), (t, i)
        bumps = int((g.key // 2).sum())
    assert bumps > 10  # the random declarations were taken back, many times


def test_blackout_a_cut_radio_is_taken_back_and_the_copies_agree() -> None:
    """blackout.yaml: UAV 0's radio alone is cut across an instant (120-150 s) and it is
    declared failed; once heard again every copy takes it back and all of them hold the same
    plan, with no live UAV declared at the end (before schema 4: declared for good)."""
    m = load_mission("missions/blackout.yaml").with_tup(15)
    env = CoverageEnv(m, 4, 1_000_000_321)
    ctl = ServiceController(m)
    ctl.reset()
    obs = env.observe()
    declared = torch.zeros(4, dtype=torch.bool)
    while not env.done:
        obs, _, _ = env.step(ctl.act(obs))
        declared |= env.gossip.failed[:, :, 0].any(-1)
    assert bool(declared.all())  # the cut radio was declared in every episode (the path is exercised)
    assert not env.gossip.failed.any()  # and taken back everywhere
    assert (env.gossip.key[:, :, 0] >= 2).all()  # at a newer incarnation
    plans = ctl.targets.plans
    for b in range(4):
        assert all(np.array_equal(plans.slot[b, 0], plans.slot[b, a]) for a in range(1, m.n_uavs)), plans.slot[b]
        pts = ctl.targets.last[b]
        assert torch.cdist(pts, pts)[~torch.eye(m.n_uavs, dtype=torch.bool)].min() > 1.0  # no two UAVs sent to one point


def four_copies():  # noqa: ANN201 - TeamPlans
    from plmarl_sitl.model.plan_motion import PlanMotion
    from plmarl_sitl.model.service import ServiceGrid, TeamPlans
    from plmarl_sitl.model.vehicle import Limits

    grid = ServiceGrid(1000.0, 1000.0, 100.0, 100.0, 350.0, 20.0)
    counts = np.zeros(100)
    for cell in (33, 35, 55, 53):
        counts[cell] = 60
    plans = TeamPlans(grid, 4, PlanMotion(Limits(20.0, 5.0, 30.0, 150.0), 100.0, 30.0, 3, lambda t: t % 15 == 0))
    line_xy = np.stack([np.full(4, 500.0), 440.0 + 40.0 * np.arange(4)], -1)
    plans.start(np.stack([line_xy] * 4)[None], counts[None])
    return plans


def same_copy(plans, a: int, b: int) -> bool:  # noqa: ANN001
    """The same plan, and the same predicted states of its live identities (a failed one's
    nominal only brakes where it was: not part of any plan)."""
    live = plans.slot[0, a] >= 0
    return (np.array_equal(plans.slot[0, a], plans.slot[0, b])
            and np.array_equal(np.nan_to_num(plans.points[0, a]), np.nan_to_num(plans.points[0, b]))
            and torch.equal(plans.motion.state[0, a, live], plans.motion.state[0, b, live]))


def test_a_plan_is_a_function_of_the_declarations_whatever_the_order_learnt() -> None:
    """UAV 1 declared at 60 and UAV 2 at 90. Copy 0 learns them in that order, copy 1 both
    at 120, copy 2 UAV 2 first and UAV 1 later (its step at 90 is undone); copy 3 also
    hears UAV 3 falsely declared at 90, then taken back. All four end with the same points,
    slots and predicted states of the survivors, to the bit."""
    plans = four_copies()
    f = lambda *ids: np.isin(np.arange(4), ids)  # noqa: E731
    s = lambda d: np.array([d.get(j, 0) for j in range(4)])  # noqa: E731
    plans.motion.advance(63, plans.all_targets())
    assert plans.settle(0, 0, f(1), s({1: 60}))
    plans.motion.advance(93, plans.all_targets())
    plans.settle(0, 0, f(1, 2), s({1: 60, 2: 90}))
    plans.settle(0, 2, f(2), s({2: 90}))
    plans.settle(0, 3, f(1, 2, 3), s({1: 60, 2: 90, 3: 90}))
    plans.motion.advance(120, plans.all_targets())
    plans.settle(0, 1, f(1, 2), s({1: 60, 2: 90}))
    plans.settle(0, 2, f(1, 2), s({1: 60, 2: 90}))
    assert not plans.settle(0, 0, f(1, 2), s({1: 60, 2: 90}))  # nothing new: nothing done
    plans.settle(0, 3, f(1, 2), s({1: 60, 2: 90}))  # 3 taken back
    plans.motion.advance(150, plans.all_targets())
    for a in (1, 2, 3):
        assert same_copy(plans, 0, a), a
    assert plans.slot[0, 0, 1] == plans.slot[0, 0, 2] == -1 and plans.slot[0, 0, 3] >= 0


def test_a_copy_that_acted_on_a_refuted_declaration_returns_to_the_plan_without_it() -> None:
    plans = four_copies()
    plans.motion.advance(93, plans.all_targets())
    assert plans.settle(0, 1, np.isin(np.arange(4), [3]), np.array([0, 0, 0, 90]))
    assert plans.slot[0, 1, 3] == -1 and not same_copy(plans, 0, 1)
    plans.motion.advance(120, plans.all_targets())
    assert plans.settle(0, 1, np.zeros(4, dtype=bool), np.zeros(4, dtype=np.int64))
    plans.motion.advance(150, plans.all_targets())
    assert same_copy(plans, 0, 1) and not plans.failed[0, 1].any() and plans.epoch[0, 1] == 0
