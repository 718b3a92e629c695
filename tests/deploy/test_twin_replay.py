"""The deployed agent against the twin, second by second: a twin episode is replayed into
real `Decision`s (each fed through its `Inbox` with the wire messages the SITL world and
the link emulator would send: states, sensing, demand maps), and at every decision each
live agent's failure flag, N_i mask, demand map and command must be the twin's
(`LearnedController`, the evaluation's controller) when misses are booked at their
instant (the replay runs each second a grace period late), which is what the twin does.
Booked a second late, as over a network, the flag still equals the twin's once booked."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import torch

from plmarl_sitl.deploy.agent.clock import MissionClock
from plmarl_sitl.deploy.agent.decision import Decision
from plmarl_sitl.deploy.agent.inbox import Inbox
from plmarl_sitl.deploy.agent.neighbours import NeighbourTable
from plmarl_sitl.deploy.agent.stats import LoopStats, Trace
from plmarl_sitl.deploy.mqtt.demand import encode_demand
from plmarl_sitl.deploy.mqtt.schema import StateMsg, Topics, encode_sense, encode_state
from plmarl_sitl.learning.eval.controllers import LearnedController
from plmarl_sitl.learning.nn.io import load_policy
from plmarl_sitl.mission import load_mission
from plmarl_sitl.model.demand import demand_map, grid_shape, is_map_instant, map_period
from plmarl_sitl.model.gossip import key_of, since_of
from plmarl_sitl.twin.env import CoverageEnv

from .conftest import MISSION, ROOT

TUP = 5
EPISODE_S = 95  # four demand maps (t = 0, 30, 60, 90)


def replay(policy_dir: Path, seed: int, fail_at: float, *, late: bool = False, placement: str = "greedy",
           track_m: float = 0.0, transit_m: float = 0.0) -> dict[str, int]:
    m = dataclasses.replace(load_mission(MISSION), n_uavs=4).with_tup(TUP).with_placement(placement).with_track_sensed(track_m)
    m = m.with_transit_plan(transit_m)
    m = dataclasses.replace(m, timing=dataclasses.replace(m.timing, episode_s=EPISODE_S))
    lp = load_policy(policy_dir, m)
    n, tau, topics = m.n_uavs, m.timing.decision_every_s, Topics()
    env = CoverageEnv(m, 1, seed, failure_prob=1.0, failure_at_s=fail_at)
    ctl = LearnedController(lp.tracker, lp.policy, m)
    ctl.reset()
    agents = []
    for i in range(n):
        clock = MissionClock(TUP, tau, 0.1, 0.15)
        clock.set_t0(0.0)
        table = NeighbourTable(n, i, m.signalling.drop_after_missed)
        dec = Decision(m, i, lp, clock, table, LoopStats(), Trace(None), topics)
        inbox = Inbox(topics, i, n, table, clock, dec.sense_history, dec.demand, wait_start=False)
        agents.append((dec, inbox))
    rows, cols = grid_shape(m.area.north_m, m.area.east_m, m.demand.cell_m)
    seen = {"decisions": 0, "f": 0, "maps": 0}
    accel = torch.zeros(1, n, 3)
    twin_f: dict[int, list[bool]] = {}

    def agent_f(dec: Decision) -> bool:  # the latched flag as of now (booked drops included)
        return dec.flag.value if lp.input_version >= 2 else dec.table.lost

    for t in range(env.horizon):
        if t > 0:
            env.physics_step(accel)
        state = env.true_state()[0]
        users = env.users.xy[0]
        if is_map_instant(t, m.demand.refresh_s, tau):
            counts = demand_map(users, m.area.north_m, m.area.east_m, m.demand.cell_m)
            payload = encode_demand(seen["maps"], t * 1000, m.demand.cell_m, rows, cols, counts.round().long().tolist())
            seen["maps"] += 1
        for i, (dec, inbox) in enumerate(agents):
            if not bool(env.alive[0, i]):
                continue  # a failed node's agent is gone
            h = env.holdings
            got = [j for j in range(n) if float(h.t_rx[0, i, j]) == t and j != i]
            sent = env.gossip.sent  # what each sender knew before this instant: its message carries it
            msgs = [encode_state(StateMsg(j, 1, t, t * 1000, tuple(h.state[0, i, j].tolist()),
                                          tuple((c, int(key_of(r)) // 2, int(since_of(r)))
                                                for c, r in enumerate(sent[0, j]) if int(key_of(r)) > 0)))
                    for j in got]
            if msgs:
                inbox.on_message(topics.rx(i), b"".join(msgs))
            d = users - state[i, :2]
            inbox.on_message(topics.sense(i), encode_sense(i, t * 1000, users[(d * d).sum(-1) <= m.radii.sensing_m**2].tolist()))
            if is_map_instant(t, m.demand.refresh_s, tau):
                inbox.on_message(topics.demand, payload)
            dec.ego = state[i].to(torch.float32)
            dec.ego_at[t] = dec.ego.clone()
            dec.second(t, sub_s=0.0 if late else dec.clock.grace_s())  # on time: instant t's misses booked at t
            if late and t - 1 in twin_f:  # instants up to t - 1 are booked now
                assert agent_f(dec) == twin_f[t - 1][i], (t, i, dec.table.dropped)
                seen["f"] += agent_f(dec)
        if t % tau:
            continue
        obs = env.observe()
        accel = ctl.act(obs)
        twin_f[t] = (ctl.perceive.flags.flag[0] if lp.input_version >= 2 else obs.fail_flag[0]).tolist()
        if late:
            seen["decisions"] += int(env.alive[0].sum())
            continue
        for i, (dec, inbox) in enumerate(agents):
            if not bool(env.alive[0, i]):
                continue
            assert dec.fail == twin_f[t][i], (t, i, dec.table.dropped)
            assert torch.equal(dec.table.mask(), obs.nbr_mask[0, i]), (t, i)
            assert torch.allclose(dec.belief[obs.nbr_mask[0, i]], ctl.perceive.beliefs.belief[0, i][obs.nbr_mask[0, i]], atol=1e-3)
            if lp.input_version >= 2:
                t_map, cells = dec.demand.for_decision(t)
                want = obs.demand[0][obs.demand[0, :, 2] > 0]
                assert t_map == t - t % map_period(m.demand.refresh_s, tau) and torch.equal(cells, want), (t, i)
            if lp.takes_plan:  # the team plan's point: the same from the agent's messages as in the twin
                assert ctl.perceive.plan is not None and ctl.perceive.plan.last is not None
                assert torch.equal(dec.target, ctl.perceive.plan.last[0, i]), (t, i, dec.target, ctl.perceive.plan.last[0, i])
                seen["plan"] = seen.get("plan", 0) + 1
                # the policy's target input: the point moved toward the sensed users (track_sensed_m)
                assert ctl.perceive.point is not None and torch.equal(dec.point, ctl.perceive.point[0, i]), (t, i)
                seen["tracked"] = seen.get("tracked", 0) + int(not torch.equal(dec.point, dec.target))
                # the failure re-plan (model/gossip.py): the same knowledge and the same copy of the plan
                assert np.array_equal(dec.plan.plans.failed[0, 0], ctl.perceive.plan.plans.failed[0, i]), (t, i)
                assert np.array_equal(dec.plan.plans.slot[0, 0], ctl.perceive.plan.plans.slot[0, i]), (t, i)
                seen["replanned"] = seen.get("replanned", 0) + int(dec.plan.plans.failed[0, 0].any())
            assert torch.allclose(torch.tensor(dec.accel), accel[0, i], atol=1e-4), (t, i, dec.accel, accel[0, i])
            if lp.takes_plan:  # in transit (transit_plan_m) the plan follower's command
                far = float((state[i, :2] - dec.target).norm()) > transit_m > 0
                seen["transit"] = seen.get("transit", 0) + int(far)
            assert inbox.rx.malformed == 0
            seen["decisions"] += 1
            seen["f"] += dec.fail
    return seen


def test_agent_decides_as_the_twin_with_the_predicted_in_range_flag(v2_policy_dir: Path) -> None:
    """Input version 2: a node fails at t = 10 s on the launch line (its neighbours still
    believe it in range: f = 1) or at t = 70 s; every decision matches the twin's, with
    f raised in some and not in others."""
    total = {"decisions": 0, "f": 0, "plan": 0, "replanned": 0}
    for seed, fail_at in ((0, 10.0), (1, 70.0)):
        seen = replay(v2_policy_dir, seed, fail_at)
        for k in total:
            total[k] += seen.get(k, 0)
    assert total["decisions"] > 180
    assert total["plan"] == total["decisions"]  # the fixture's policy takes the team plan
    assert 0 < total["f"] < total["decisions"], total
    assert total["replanned"] > 0, total  # decisions made on a plan re-solved after the failure


def test_agent_places_as_the_twin_with_the_search_and_the_learnt_placement(v2_policy_dir: Path) -> None:
    """`placement: search` and `placement: learned` (model/placement.py, issue 24.3): the
    agents' plans, re-solved after the failure too, are the twin's at every decision."""
    for placement in ("search", "learned"):
        seen = replay(v2_policy_dir, 1, 70.0, placement=placement)
        assert seen["decisions"] > 90 and seen["plan"] == seen["decisions"], (placement, seen)
        assert seen["replanned"] > 0, (placement, seen)


def test_agent_follows_its_sensed_users_as_the_twin() -> None:
    """`track_sensed_m` (model/sensed_track.py, issue 24.3): the point moved toward the sensed
    users is the twin's at every decision, and it moves at most decisions."""
    seen = replay(ROOT / "policies" / "pl-marl", 1, 70.0, track_m=30.0)
    assert seen["decisions"] > 90 and seen["plan"] == seen["decisions"], seen
    assert seen["tracked"] > seen["decisions"] // 2, seen


def test_agent_flies_the_plan_follower_in_transit_as_the_twin() -> None:
    """`transit_plan_m` (model/plan_follower.py): beyond it from its plan point the agent's
    command is the plan follower's, within it the policy's; both the twin's at every decision."""
    seen = replay(ROOT / "policies" / "pl-marl", 1, 70.0, transit_m=50.0)
    assert seen["decisions"] > 90 and seen["plan"] == seen["decisions"], seen
    assert 0 < seen["transit"] < seen["decisions"], seen  # both commands were flown


def test_flag_booked_late_still_equals_the_twins(v2_policy_dir: Path) -> None:
    """Misses booked a second after their instant (a grace period, as over a network): each
    drop is judged with the beliefs of the decision at which the twin saw it, so the flag
    equals the twin's as soon as the drop is booked."""
    seen = replay(v2_policy_dir, 0, 10.0, late=True)
    assert seen["decisions"] > 90 and seen["f"] > 0


def test_a_version_1_policy_runs_as_it_was_trained() -> None:
    """The policies shipped before issue 12 (policies/wave1): no demand argument, f = a neighbour dropped."""
    seen = replay(ROOT / "policies" / "wave1" / "pl-marl", 0, 50.0)
    assert seen["decisions"] > 100 and seen["f"] > 0
