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
from plmarl_sitl.model.gossip import Gossip, extends, key_of, may_predict
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
    learns it at 90 and hears 3 at that very instant: it takes 3 back at once (incarnation 1,
    epoch 90); 3 learns the declaration from 2 at 90 too and takes itself back alike; the
    newer incarnation then beats the declaration everywhere, one hop per instant."""
    n = 4
    g = Gossip(1, n)
    mine = torch.zeros(1, n, n, dtype=torch.bool)
    mine[0, 0, 3] = True
    g.declare(mine, torch.tensor([[60, 0, 0, 0]]))
    keys = []
    for t in (75, 90, 105, 120):
        g.receive(line(n, n), t)
        keys.append(g.key[0, :, 3].tolist())
    assert keys == [[1, 1, 0, 0],  # 1 learns the declaration from 0
                    [1, 1, 2, 0],  # 2 learns it and hears 3 at once: takes it back (3 heard 2's older state)
                    [1, 2, 2, 2],  # incarnation 1 reaches 1 and 3
                    [2, 2, 2, 2]]  # and 0
    assert not g.failed.any()
    assert g.epoch[0].tolist() == [90] * 4  # the taking back is a re-plan at 90: its epoch spreads by max
    for t in (135, 150):
        g.receive(line(n, n), t)
    assert g.epoch[0].tolist() == [90] * 4 and g.key[0, :, 3].tolist() == [2] * 4  # converged, no leader


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
    g.receive(hears, 45)
    assert g.key[0, 3, 3] == 2 and g.epoch[0, 3] == 45  # itself: incarnation 1
    assert g.failed[0, 0, 3] and g.failed[0, 1, 3]
    hears[0, 0, 3] = hears[0, 1, 3] = True  # now 0 and 1 hear 3 (3's message carries incarnation 1)
    g.receive(hears, 60)
    assert not g.failed.any() and g.key[0, :, 3].tolist() == [2, 2, 0, 2]
    assert g.epoch[0, :2].tolist() == [45, 45]  # the epoch of 3's own taking back, carried with it


def test_a_dead_uav_stays_declared_and_a_new_declaration_of_a_newer_incarnation_wins() -> None:
    """A refutation needs a message of the identity (or of someone who heard one): a dead UAV
    is never taken back. Declared again at incarnation 1, it is failed again everywhere."""
    n = 3
    g = Gossip(1, n)
    g.key[0, :, 2] = 2  # everyone: identity 2 alive at incarnation 1
    mine = torch.zeros(1, n, n, dtype=torch.bool)
    mine[0, 0, 2] = True
    g.declare(mine, torch.tensor([[90, 0, 0]]))
    assert g.key[0, 0, 2] == key_of(True, 1) == 3
    for t in (105, 120):
        g.receive(line(n, 2), t)  # 2 is dead: heard by nobody
    assert g.failed[0, :2, 2].all() and g.epoch[0, :2].tolist() == [90, 90]


def test_may_predict_refuses_a_sender_that_acted_on_a_declaration_since_refuted() -> None:
    """The receiver holds 3 alive at incarnation 1 (its plan rolled back); a sender whose last
    message knew 3 declared at incarnation 0 flew the re-plan without 3: not predictable. A
    sender that never knew of the declaration flew the plan the receiver rolled back to."""
    key = torch.tensor([0, 0, 0, 2])
    acted = torch.tensor([0, 0, 0, 1])
    never = torch.tensor([0, 0, 0, 0])
    assert not bool(extends(key, acted).all()) and bool(extends(key, never).all())
    heard = torch.stack([acted, never]).unsqueeze(0)  # (1, M=2, N)
    ok = may_predict(heard, torch.tensor([[60, 0]]), key.unsqueeze(0), torch.tensor([90]), 90)
    assert ok.tolist() == [[False, True]]
    assert not Known(0, 90, {3: 1}).extends(Known(1 << 3, 60)) and Known(0, 90, {3: 1}).extends(Known(0, 0))


def wire(known: Known, sender: int, t: int) -> Known:
    """The knowledge as a receiver decodes it from the sender's state message of instant t."""
    raw = encode_state(StateMsg.with_knowledge(sender, 1, t, t * 1000, (0.0,) * 6, known))
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
        g.receive(hears, t)
        d = t + 3  # a decision between instants: declare a random teammate not heard at t
        mine = torch.zeros(1, n, n, dtype=torch.bool)
        for i, a in enumerate(agents):
            if rng.random() < 0.3:
                j = rng.choice([j for j in range(n) if j != i and not hears[0, i, j]] or [None])
                if j is not None and not a.view(before=d + 1).failed >> j & 1:
                    mine[0, i, j] = True
                    a.learn(d, Known(1 << j, t, a.view(before=d + 1).inc))
        g.declare(mine, torch.where(mine.any(-1), torch.full((1, n), t), torch.zeros(1, n, dtype=torch.int64)))
        for i, a in enumerate(agents):
            v = a.view(before=d + 1)
            assert [v.key(j) for j in range(n)] == g.key[0, i].tolist(), (t, i)
            assert v.epoch == int(g.epoch[0, i]), (t, i)
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
