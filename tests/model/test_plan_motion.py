"""The plan-aware prediction in numpy (model/plan_motion.py) is the torch flight it replaced,
bit for bit: `goto_accel` held for tau, `step_point_mass` each second, on the same shapes.
The reference below is that torch loop; the states must be equal, not close, because every
agent and the twin must assign a re-plan from the same positions."""

import numpy as np
import pytest
import torch

from plmarl_sitl.model.plan_motion import PlanMotion, _goto_accel
from plmarl_sitl.model.vehicle import Limits, goto_accel, step_point_mass

LIM = Limits(20.0, 5.0, 40.0, 150.0)
TAU = 3


def _torch_flight(state: torch.Tensor, goal_xy: np.ndarray, t0: int, t1: int, plan_alt: float) -> list[torch.Tensor]:
    """The former PlanMotion.advance: every second's state from t0 + 1 to t1."""
    goal = torch.from_numpy(np.ascontiguousarray(goal_xy, dtype=np.float64))
    goal = torch.where(torch.isnan(goal), state[..., :2], goal)
    goal = torch.cat([goal, torch.full_like(goal[..., :1], -plan_alt)], -1)
    out, accel = [], None
    for t in range(t0, t1):
        if t % TAU == 0 or accel is None:
            accel = goto_accel(state[..., :3], state[..., 3:], goal, LIM.max_speed, LIM.max_accel, time_const=float(TAU))
        p, v = step_point_mass(state[..., :3], state[..., 3:], accel, 1.0, LIM)
        state = torch.cat([p, v], -1)
        out.append(state)
    return out


@pytest.mark.parametrize("shape", [(1, 1, 4), (1, 1, 20), (1, 1, 100), (2, 5, 5)])
def test_numpy_flight_equals_the_torch_flight_bit_for_bit(shape):
    rng = np.random.default_rng(sum(shape))
    launch = rng.uniform(0, 1500, shape + (2,))
    motion = PlanMotion(LIM, 100.5, 60.0, TAU, lambda t: t % 5 == 0)
    motion.start(launch)
    ref = torch.from_numpy(motion.now.copy())
    t = 0
    # transit at V_max (the event solver), arrival and hover (free flight), a new plan, a failed identity
    for leg in range(3):
        targets = rng.uniform(0, 1500, shape + (2,))
        if leg == 2:
            targets[..., 0, :] = np.nan
        for _ in range(40 if leg < 2 else 15):
            states = _torch_flight(ref, targets, t, t + TAU, 100.5)
            motion.advance(t + TAU, targets)
            t += TAU
            ref = states[-1]
            assert np.array_equal(motion.now, ref.numpy())
            for s, st in zip(range(t - TAU + 1, t + 1), states, strict=True):
                if s % 5 == 0:
                    assert np.array_equal(motion.kept[s], st.numpy())


def test_goto_accel_in_numpy_equals_torch_at_every_distance():
    rng = np.random.default_rng(3)
    n = 5000
    scale = rng.choice([1e-13, 1e-6, 1e-2, 1.0, 30.0, 2000.0], size=(n, 1))
    p = rng.uniform(0, 3000, (n, 3))
    goal = p + rng.standard_normal((n, 3)) * scale
    v = rng.standard_normal((n, 3)) * rng.choice([0.0, 1e-14, 1.0, 20.0], size=(n, 1))
    want = goto_accel(torch.from_numpy(p), torch.from_numpy(v), torch.from_numpy(goal), LIM.max_speed, LIM.max_accel,
                      time_const=float(TAU)).numpy()
    assert np.array_equal(_goto_accel(p, v, goal, LIM, float(TAU)), want)


def test_replay_equals_a_flight_switched_at_the_epoch():
    rng = np.random.default_rng(7)
    launch = rng.uniform(0, 1000, (1, 2, 12, 2))
    motion = PlanMotion(LIM, 100.5, 60.0, TAU, lambda t: t % 5 == 0)
    motion.start(launch)
    first = rng.uniform(0, 1000, (1, 2, 12, 2))
    motion.advance(30, first)
    later = rng.uniform(0, 1000, (12, 2))
    motion.replay(0, 1, 15, later)
    at15 = torch.from_numpy(motion.kept[15][0, 1].copy())
    states = _torch_flight(at15, later, 15, 30, 100.5)
    assert np.array_equal(motion.now[0, 1], states[-1].numpy())
    assert np.array_equal(motion.kept[20][0, 1], states[4].numpy())
    assert np.array_equal(motion.kept[25][0, 1], states[9].numpy())


def _mixed_batch(rng: np.random.Generator, m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """States and commands of every kind the solver separates: free flight, at V_max
    (pushing on or turning), at a band edge, resting on the floor, past the limits, a NaN command."""
    p = np.concatenate([rng.uniform(0, 1000, (m, 2)), -rng.uniform(LIM.alt_min, LIM.alt_max, (m, 1))], -1)
    v = rng.standard_normal((m, 3)) * rng.choice([0.0, 1.0, 10.0], size=(m, 1))
    acc = rng.standard_normal((m, 3)) * rng.choice([0.0, 1.0, 4.0, 9.0], size=(m, 1))
    kind = rng.integers(0, 7, m)
    at_vmax = kind == 1
    v[at_vmax] *= LIM.max_speed / np.linalg.norm(v[at_vmax] + 1e-30, axis=-1, keepdims=True)
    p[kind == 2, 2] = -LIM.alt_max
    p[kind == 3, 2] = -LIM.alt_min
    v[kind == 3] = 0.0
    acc[kind == 3] = [0.0, 0.0, 1.0]
    v[kind == 4] *= 5.0  # faster than V_max: projected back
    acc[kind == 5] = np.nan
    p[kind == 6, 2] = -LIM.alt_max - 3.0  # above the band: clamped
    return p, v, acc


@pytest.mark.parametrize("m", [1, 5, 20, 100, 300])
def test_numpy_step_per_vehicle_equals_the_whole_batch_through_torch(m):
    from plmarl_sitl.model.vehicle import step_point_mass_np

    rng = np.random.default_rng(m)
    for _ in range(30):
        p, v, acc = _mixed_batch(rng, m)
        want_p, want_v = step_point_mass(torch.from_numpy(p), torch.from_numpy(v), torch.from_numpy(acc), 1.0, LIM)
        got_p, got_v = step_point_mass_np(p, v, acc, 1.0, LIM)
        assert np.array_equal(got_p, want_p.numpy()) and np.array_equal(got_v, want_v.numpy())


def test_link_tables_are_kept_while_the_predictions_are_and_recomputed_when_they_change():
    from plmarl_sitl.deploy.agent.plan import LinkTables

    tables, calls = LinkTables(), []
    pred = np.zeros((1, 1, 4, 3))

    def compute():
        calls.append(1)
        return pred[..., 0] > len(calls)

    first = tables.get(("clear", 15), (pred,), compute)
    assert tables.get(("clear", 15), (pred.copy(),), compute) is first and len(calls) == 1
    pred[0, 0, 2, 1] = 1e-9  # a re-plan re-flew the prediction in place: the table is stale
    assert tables.get(("clear", 15), (pred,), compute) is not first and len(calls) == 2
    for k in range(LinkTables.KEEP + 3):
        tables.get(("clear", 30 + k), (pred,), compute)
    assert len(tables.tables) == LinkTables.KEEP


def test_numpy_step_of_a_hovering_team_equals_torch():
    """The common second: every vehicle well inside every limit (`_clearly_inside`'s shortcut)."""
    from plmarl_sitl.model.vehicle import _clearly_inside, step_point_mass_np

    rng = np.random.default_rng(11)
    for m in (1, 4, 20, 100):
        p = np.concatenate([rng.uniform(0, 3000, (m, 2)), -rng.uniform(60, 120, (m, 1))], -1)
        v = rng.uniform(-1, 1, (m, 3)) * rng.choice([1e-14, 1e-3, 5.0], size=(m, 1))
        acc = rng.uniform(-1, 1, (m, 3)) * rng.choice([0.0, 1e-12, 1.0], size=(m, 1))
        assert _clearly_inside(p, v, acc, 1.0, LIM)
        want_p, want_v = step_point_mass(torch.from_numpy(p), torch.from_numpy(v), torch.from_numpy(acc), 1.0, LIM)
        got_p, got_v = step_point_mass_np(p, v, acc, 1.0, LIM)
        assert np.array_equal(got_p, want_p.numpy()) and np.array_equal(got_v, want_v.numpy())


@pytest.mark.parametrize("shape", [(1, 1, 20), (2, 3, 6)])
def test_seconds_flown_when_read_equal_seconds_flown_at_each_advance(shape):
    """`advance` only books the seconds; they are flown when a state is read. A motion read
    only at some instants (as a deployed agent's failure check reads it) holds the same
    states, kept instants and re-flown copies as one read after every advance, through
    transit, a new plan held for several decisions, a re-plan replayed from an epoch and a
    failed identity's NaN point (flown at once: it stays where it is at the call)."""
    rng = np.random.default_rng(sum(shape) + 7)
    launch = rng.uniform(0, 1500, shape + (2,))
    eager = PlanMotion(LIM, 100.5, 60.0, TAU, lambda t: t % 15 == 0)
    lazy = PlanMotion(LIM, 100.5, 60.0, TAU, lambda t: t % 15 == 0)
    eager.start(launch)
    lazy.start(launch)
    t, deferred = 0, 0
    for leg in range(5):
        targets = rng.uniform(0, 1500, shape + (2,))
        if leg == 3:
            targets[..., 1, :] = np.nan
        for _ in range(12):
            t += TAU
            eager.advance(t, targets)
            lazy.advance(t, targets.copy())  # equal points in another array: still one stretch
            deferred += lazy.flown < lazy.t
            assert lazy.t == eager.t == t
            eager.now  # noqa: B018 - read: flown now
            if t % 15 == 6:  # the failure check's read: an instant before now
                assert np.array_equal(lazy.at_array(t - 6), eager.at_array(t - 6))
            if leg == 4 and t % 30 == 0:  # a re-plan re-flies copy (0, 0) from the last instant
                new = rng.uniform(0, 1500, shape[2:] + (2,))
                eager.replay(0, 0, t - 15, new)
                lazy.replay(0, 0, t - 15, new)
    assert deferred > 20  # the lazy motion did defer
    assert np.array_equal(lazy.now, eager.now)
    assert sorted(lazy.kept) == sorted(eager.kept)
    assert all(np.array_equal(lazy.kept[s], eager.kept[s]) for s in eager.kept)
