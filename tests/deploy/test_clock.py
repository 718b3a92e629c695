"""The agent's mission clock on its own: when a second is due, when an instant's misses are
booked, how t0, T_up changes and the observed speedup move it."""

from __future__ import annotations

import math

import pytest

from plmarl_sitl.deploy.agent.clock import MissionClock
from plmarl_sitl.deploy.agent.neighbours import NeighbourTable
from plmarl_sitl.deploy.mqtt.schema import INSTANT_WAIT_MIN_S

TUP, TAU = 15, 3
SETTLE_MIN, SETTLE_WALL = 0.1, 0.15


def started(t0: float = 0.0, boot_s: float = 0.0, tup: int = TUP) -> MissionClock:
    clock = MissionClock(tup, TAU, SETTLE_MIN, SETTLE_WALL)
    clock.observe(boot_s, 0.0)
    clock.set_t0(t0)
    return clock


def never(k: int) -> bool:
    return False


def always(k: int) -> bool:
    return True


def test_a_plain_second_is_due_at_its_start_and_not_before() -> None:
    clock = started()
    assert not clock.second_due(1, 0.999, False, never)
    assert clock.second_due(1, 1.0, False, never)  # not an instant, not a decision: no wait
    assert clock.second_due(3, 3.0, False, never)  # a decision second once sensing has been seen or given up on


def test_an_instant_waits_the_minimum_settle_even_when_all_delivered() -> None:
    clock = started()
    assert not clock.second_due(15, 15.0, False, always)
    assert not clock.second_due(15, 15.0 + SETTLE_MIN - 0.01, False, always)
    assert clock.second_due(15, 15.0 + SETTLE_MIN, False, always)


def test_an_instant_waits_until_delivered() -> None:
    clock = started()
    asked: list[int] = []

    def delivered(k: int) -> bool:
        asked.append(k)
        return len(asked) > 1

    assert not clock.second_due(15, 15.12, False, delivered)
    assert clock.second_due(15, 15.13, False, delivered)
    assert asked == [15, 15]


def test_an_instant_is_due_once_the_world_closed_it() -> None:
    clock = started()
    assert not clock.second_due(15, 15.12, False, never)
    clock.on_closed(15.0)
    assert clock.second_due(15, 15.12, False, never)
    assert not clock.second_due(30, 30.12, False, never)  # a later instant still waits


def test_a_late_closed_announcement_never_moves_an_instant_back() -> None:
    clock = started()
    assert clock.closed_t == -math.inf
    clock.on_closed(30.0)
    clock.on_closed(15.0)
    assert clock.closed_t == 30.0


def test_an_instant_waits_at_most_the_grace_bound() -> None:
    clock = started()
    assert clock.settle_max_s() == max(INSTANT_WAIT_MIN_S, SETTLE_WALL)
    bound = 15.0 + clock.settle_max_s()
    assert not clock.second_due(15, bound - 0.001, False, never)
    assert clock.second_due(15, bound, False, never)


def test_the_wait_bound_scales_with_the_observed_speedup() -> None:
    clock = MissionClock(TUP, TAU, SETTLE_MIN, SETTLE_WALL)
    clock.observe(0.0, 100.0)
    clock.observe(5.0, 100.5)  # under a wall second: not measured yet
    assert clock.rate is None
    clock.observe(10.0, 101.0)
    assert clock.rate == 10.0
    assert clock.settle_max_s() == pytest.approx(SETTLE_WALL * 10.0)
    clock.observe(30.0, 102.0)  # 20x over the last second: smoothed
    assert clock.rate == 15.0
    clock.observe(29.0, 103.0)  # vehicle time went back (a reboot): ignored
    assert clock.rate == 15.0


def test_the_first_decision_waits_for_sensing_up_to_the_bound() -> None:
    clock = started()
    assert not clock.second_due(3, 3.0, True, always)
    assert not clock.second_due(3, 3.0 + clock.settle_max_s() - 0.001, True, always)
    assert clock.second_due(3, 3.0 + clock.settle_max_s(), True, always)
    assert clock.second_due(4, 4.0, True, never)  # not a decision second


def test_t0_sets_the_first_second_and_instants() -> None:
    clock = started(t0=2.0, boot_s=20.5)  # the mission began 18.5 s before this agent
    assert (clock.first_k, clock.next_k) == (19, 19)
    assert clock.next_pub_k == clock.next_close == 30
    assert clock.mission_s() == 18.5 and clock.in_mission()
    early = started(t0=10.0, boot_s=4.0)
    assert early.first_k == 0 and early.next_pub_k == 0 and not early.in_mission()


def test_the_state_is_published_once_at_each_instant() -> None:
    clock = started()
    assert clock.states_due(0.0) == [0]
    assert clock.states_due(14.9) == []
    assert clock.states_due(15.0) == [15]
    assert clock.states_due(15.1) == []
    assert clock.states_due(46.0) == [30, 45]


def test_a_new_tup_aligns_the_next_instant() -> None:
    clock = started()
    clock.observe(31.5, 0.0)
    clock.set_tup(5)
    assert clock.next_pub_k == clock.next_close == 35
    assert clock.second_due(33, 33.0, False, never)  # 33 % 5: no longer waits ...
    assert not clock.second_due(35, 35.0, False, always)  # ... 35 does


@pytest.mark.parametrize("telemetry_first", [False, True], ids=["change-first", "telemetry-first"])
@pytest.mark.parametrize(("change_at", "new_tup", "published"), [
    (10, 5, [0, 15, 20, 25]),  # 10 is a multiple of the new T_up only: not an instant (the world's rule)
    (15, 5, [0, 15, 20, 25]),  # 15 is an instant under the old T_up: still owed, then multiples of 5
    (15, 10, [0, 15, 20]),
])
def test_lockstep_tup_change_is_independent_of_arrival_order(telemetry_first, change_at, new_tup, published) -> None:
    """Lockstep: the change arrives in second `change_at` (before its tick); whether that
    second's first telemetry came before it is wall-clock order and must not matter."""
    clock = MissionClock(TUP, TAU, SETTLE_MIN, SETTLE_WALL, lockstep=True)
    clock.observe(0.0, 0.0)
    clock.set_t0(0.0)
    out = []
    for tenth in range(0, 260):
        tm = tenth / 10
        k = math.floor(tm + 1e-9)
        if k == change_at and tenth % 10 == 0 and not telemetry_first:
            clock.set_tup(new_tup)
        clock.observe(tm, 0.0)
        out += clock.states_due(tm)
        if k == change_at and tenth % 10 == 0 and telemetry_first:
            clock.set_tup(new_tup)
        if tenth % 10 == 0:
            clock.next_k = k + 1  # second k processed at its first sample, after its tick
    assert out == published


def test_grace_is_half_a_wall_second_within_the_wait_bound_and_half_tup() -> None:
    clock = started()
    assert clock.grace_s() == 0.5
    clock.observe(0.0, 0.0)
    clock.observe(10.0, 1.0)  # 10x: 5 vehicle seconds, under T_up / 2
    assert clock.grace_s() == pytest.approx(5.0)
    fast = started(tup=5)
    fast.observe(0.0, 0.0)
    fast.observe(10.0, 1.0)
    assert fast.grace_s() == 2.5


def test_misses_are_booked_once_the_grace_has_passed() -> None:
    clock = started()  # grace 0.5 s: instant k is booked when second k is processed 0.5 s late, else at k + 1
    assert clock.instants_to_book(0, 0.4) == []
    assert clock.instants_to_book(0, 0.5) == [0]
    assert clock.instants_to_book(1) == []
    assert clock.instants_to_book(15) == []
    assert clock.instants_to_book(16) == [15]
    assert clock.instants_to_book(47) == [30, 45]  # a stalled agent books every instant it skipped


def test_misses_counted_and_a_silent_neighbour_dropped() -> None:
    """Booked instants go to the neighbour table: a neighbour that delivered is not missed,
    one that stopped is missed at each booked instant and dropped after `drop` of them."""
    clock = started()
    table = NeighbourTable(3, 0, drop_after_missed=2)
    dropped = []
    for k in range(0, 62):
        if k % TUP == 0:
            table.on_state(1, float(k), (0.0,) * 6)
            if k < 30:
                table.on_state(2, float(k), (0.0,) * 6)
        for inst in clock.instants_to_book(k):
            dropped += [(inst, j) for j in table.close_instant(float(inst))]
    assert table.missed == [0, 0, 3]  # instants 30, 45, 60 (booked at 61)
    assert dropped == [(45, 2)] and table.lost
