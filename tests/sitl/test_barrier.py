"""The lockstep barrier's rule (`sitl.lockstep.Barrier`) on the fleet's stamp arrays."""

import math
from types import SimpleNamespace

import numpy as np
import pytest

from plmarl_sitl.sitl.lockstep import DEFAULT_STARTUP_SPEEDUP, Barrier, speedup_or_default


def _fleet(telemetry_ms, answered_ms):
    # The barrier reads only these of `autopilot.fleet.Fleet`.
    return SimpleNamespace(telemetry_ms=np.array(telemetry_ms, dtype=np.int64),
                           answered_ms=np.array(answered_ms, dtype=np.int64), answered_wall=-math.inf)


def test_members_are_live_joined_and_not_failed():
    b = Barrier(_fleet([500, 500, 500, 500], [500, -1, 400, 300]))
    assert b.members([True, True, True, False]) == [0, 2]
    b.fail(2, "test")
    assert b.members([True, True, True, False]) == [0]


def test_owing_is_members_behind_their_telemetry():
    f = _fleet([500, 500, 500], [500, 400, -1])
    b = Barrier(f)
    assert b.owing([True, True, True]) == [1]  # 2 has not joined: start-up is not lockstepped
    f.answered_ms[1] = 500
    assert b.owing([True, True, True]) == []
    f.telemetry_ms[:] = 600
    assert b.owing([True, True, True]) == [0, 1]
    assert b.owing([False, True, True]) == [1]  # a dead vehicle owes nothing


def test_all_joined_counts_failed_and_dead_as_done():
    b = Barrier(_fleet([100, 100, 100], [100, -1, -1]))
    assert not b.all_joined([True, True, True])
    b.fail(1, "test")
    assert not b.all_joined([True, True, True])
    assert b.all_joined([True, True, False])


def test_straggler_is_overdue_only_after_the_bound_on_the_same_answer():
    f = _fleet([100], [50])
    b = Barrier(f, straggler_s=2.0)
    assert b.overdue([0], wall_s=10.0) == []
    assert b.wait_left([0], wall_s=11.0) == pytest.approx(1.0)
    assert b.overdue([0], wall_s=11.9) == []
    f.telemetry_ms[0] = 200  # a new sample restarts the clock
    assert b.overdue([0], wall_s=12.5) == []
    assert b.overdue([0], wall_s=14.5) == [0]


def test_straggler_bound_counts_only_time_without_progress():
    # A slow machine: the others' answers trickle in; the one left owing fails only once
    # nobody has answered for the bound (issue 25: N = 100 at load 30-60).
    f = _fleet([100, 100, 100], [50, 50, 50])
    b = Barrier(f, straggler_s=2.0)
    assert b.overdue([0, 1, 2], wall_s=10.0) == []
    f.answered_ms[1], f.answered_wall = 100, 11.5  # member 1 answers late
    assert b.overdue([0, 2], wall_s=12.5) == []
    assert b.wait_left([0, 2], wall_s=12.5) == pytest.approx(1.0)
    f.answered_ms[2], f.answered_wall = 100, 13.0
    assert b.overdue([0], wall_s=14.9) == []
    assert b.overdue([0], wall_s=15.0) == [0]  # 2 s after the last answer


def test_a_restart_gives_the_held_answers_the_whole_bound():
    f = _fleet([100, 100], [50, 50])
    b = Barrier(f, straggler_s=2.0)
    assert b.overdue([0, 1], wall_s=10.0) == []  # held for the tick, which the world sends late
    b.restart(11.8)
    assert b.overdue([0, 1], wall_s=13.0) == []
    assert b.overdue([0, 1], wall_s=13.8) == [0, 1]


def test_start_up_pace_defaults():
    assert speedup_or_default(None, lockstep=False) == 1.0
    assert speedup_or_default(None, lockstep=True) == DEFAULT_STARTUP_SPEEDUP
    assert speedup_or_default(3.0, lockstep=True) == 3.0
