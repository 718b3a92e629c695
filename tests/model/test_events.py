"""The mission event schedule on its own: seconds, order, what is in force."""

import dataclasses
import math
from pathlib import Path

import pytest
import torch

from plmarl_sitl.config import ConfigError
from plmarl_sitl.mission import Event, Failure, load_mission
from plmarl_sitl.model.events import GPS_FAILSAFE_S, EventSchedule, failure_times

BASE_PATH = Path("missions/paper_urban.yaml").resolve()
BASE = load_mission(BASE_PATH)


def _schedule(*events: dict, failures: tuple[Failure, ...] = ()) -> EventSchedule:
    return EventSchedule.of(dataclasses.replace(BASE, events=tuple(Event(**e) for e in events), failures=failures))


def test_events_start_and_end_at_whole_seconds_starts_before_ends():
    s = _schedule(
        {"type": "broker_outage", "at_s": 10, "duration_s": 20},
        {"type": "link_blackout", "at_s": 29.5, "duration_s": 0.2, "uavs": (1,)},
        {"type": "node_failure", "at_s": 30, "uav": 2},
    )
    assert [(c.event.type, c.ends) for c in s.changes_at(30)] == [
        ("link_blackout", False), ("node_failure", False), ("broker_outage", True), ("link_blackout", True)]
    assert s.changes_at(29) == [] and s.broker_down(29) and not s.broker_down(30)
    assert s.cut_off(29) == frozenset() and s.cut_off(30) == frozenset()  # ceil(29.5) == ceil(29.7): never in force


def test_failures_list_and_node_failure_events_are_one_list_in_time_order():
    s = _schedule({"type": "node_failure", "at_s": 40, "uav": 1}, {"type": "node_failure", "at_s": 5.5, "uav": 3},
                  failures=(Failure(at_s=60, uav=1),))
    assert [(e.at_s, e.uav) for e in s.events] == [(5.5, 3), (40, 1), (60, 1)]
    assert s.failure_s() == (math.inf, 40.0, math.inf, 6.0)


def test_tup_in_force_is_the_latest_change_in_time():
    s = _schedule({"type": "tup_change", "at_s": 50, "tup_s": 5}, {"type": "tup_change", "at_s": 20, "tup_s": 10})
    assert [s.tup_at(t) for t in (0, 19, 20, 49, 50, 200)] == [15, 15, 10, 10, 5, 5]


def test_overlapping_gnss_noise_adds_in_quadrature():
    s = _schedule({"type": "gnss_noise", "at_s": 0, "std_m": 3.0}, {"type": "gnss_noise", "at_s": 10, "std_m": 4.0, "duration_s": 5, "uavs": (0,)})
    assert s.gnss_std_m(12) == (5.0, 3.0, 3.0, 3.0) and s.gnss_std_m(15) == (3.0, 3.0, 3.0, 3.0)


def test_failure_curriculum_adds_one_random_failure_to_the_chosen_episodes():
    s = _schedule(failures=(Failure(at_s=30, uav=0),))
    fail_at = failure_times(s, 1000, torch.Generator().manual_seed(0), failure_prob=0.3, failure_at_s=99.5)
    assert bool((fail_at[:, 0] == 30).all())  # an earlier failure stands
    extra = (fail_at[:, 1:] == 100).sum(-1)  # at most one more, in 0.3 x 3/4 of the episodes
    assert int(extra.max()) == 1 and 0.19 < float(extra.float().mean()) < 0.26
    assert torch.equal(failure_times(s, 3, torch.Generator()), torch.tensor([[30.0, math.inf, math.inf, math.inf]] * 3, dtype=torch.float64))


# ---------------------------------------------------------------------------- autopilot faults
def test_autopilot_faults_take_uavs_out_at_their_measured_second():
    """motor_failure: at once; gps_loss: when the EKF failsafe lands the UAV (GPS_FAILSAFE_S
    after the loss), if the loss lasts that long; a shorter one is bridged."""
    s = _schedule(
        {"type": "gps_loss", "at_s": 40.5, "duration_s": 30, "uavs": (0, 2)},
        {"type": "gps_loss", "at_s": 50, "duration_s": GPS_FAILSAFE_S - 1, "uavs": (1,)},
        {"type": "motor_failure", "at_s": 100, "uav": 3},
    )
    assert s.failure_s() == (41 + GPS_FAILSAFE_S, math.inf, 41 + GPS_FAILSAFE_S, 100.0)
    assert [(u, e.type) for u, e in s.fault_failures_at(41 + GPS_FAILSAFE_S)] == [(0, "gps_loss"), (2, "gps_loss")]
    assert [(u, e.type) for u, e in s.fault_failures_at(100)] == [(3, "motor_failure")]
    assert s.fault_failures_at(57) == []  # uav 1's short loss never takes it out
    everyone = _schedule({"type": "gps_loss", "at_s": 10})  # no uavs: all of them, to the end
    assert everyone.failure_s() == (10.0 + GPS_FAILSAFE_S,) * BASE.n_uavs


def test_on_px4_a_gps_loss_takes_no_uav_out_and_a_motor_failure_does_at_once():
    """PX4 1.17 SIH, measured: under acceleration setpoints a GPS loss leaves the vehicle in
    OFFBOARD under its agent (docs/CONFORMANCE.md, "Autopilot faults on PX4")."""
    events = ({"type": "gps_loss", "at_s": 40.5, "duration_s": 30, "uavs": (0, 2)},
              {"type": "motor_failure", "at_s": 100, "uav": 3})
    ardupilot = _schedule(*events)
    px4 = dataclasses.replace(ardupilot, autopilot="px4")
    assert ardupilot.failure_s() == (41 + GPS_FAILSAFE_S, math.inf, 41 + GPS_FAILSAFE_S, 100.0)
    assert px4.failure_s() == (math.inf, math.inf, math.inf, 100.0)
    assert all(px4.fault_failures_at(t) == [] for t in range(0, 100))
    assert [(u, e.type) for u, e in px4.fault_failures_at(100)] == [(3, "motor_failure")]
    with pytest.raises(ValueError, match="no measured fault reactions"):
        dataclasses.replace(ardupilot, autopilot="betaflight")


def test_autopilot_fault_events_are_validated_with_their_yaml_path(tmp_path):
    cases = {
        "{type: motor_failure, at_s: 10}": "events[0].uav: is required for a motor_failure event",
        "{type: motor_failure, at_s: 10, uav: 7}": "events[0].uav: must be < n_uavs (4)",
        "{type: motor_failure, at_s: 10, uav: 1, duration_s: 5}": "events[0].duration_s: not used by a motor_failure",
        "{type: gps_loss, at_s: 10, uav: 1}": "events[0].uav: not used by a gps_loss event",
        "{type: gps_loss, at_s: 10, uavs: [9]}": "events[0].uavs: must be < n_uavs (4)",
        "{type: gps_loss, at_s: 10, duration_s: 0}": "events[0].duration_s",
    }
    for event, message in cases.items():
        path = tmp_path / "m.yaml"
        path.write_text(f"extends: {BASE_PATH}\nname: bad\nevents:\n  - {event}\n")
        with pytest.raises(ConfigError) as err:
            load_mission(path)
        assert message in str(err.value) and str(path) in str(err.value), (event, str(err.value))
    shipped = load_mission("missions/autopilot_faults.yaml")
    assert {e.type for e in shipped.events} == {"gps_loss", "motor_failure"}
