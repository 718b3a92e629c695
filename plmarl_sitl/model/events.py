"""Mission events on the mission clock: one schedule for the twin and the SITL world.

A mission's events (its `failures` list and its `events`: node failures, link blackouts,
broker outages, T_up changes, GNSS noise) take effect at whole mission seconds, the only
instants either world acts on: an event at `at_s` starts at second ceil(at_s), and one
with a duration ends at second ceil(at_s + duration_s); in between it is in force.

The schedule answers two questions about the same data:

* what is in force at second t (`failure_s`, `tup_at`, `broker_down`, `cut_off`,
  `active`, `gnss_std_m`): the twin asks while it steps;
* what changes at second t (`changes_at`): the SITL world applies the changes it owns
  (vehicles, links, GNSS noise, T_up, autopilot faults) and the launcher the rest (a failed
  node's agent process, the broker gate) and logs them all.

Autopilot faults (gps_loss, motor_failure) reach the autopilot's own fault injection in
SITL; the twin has no autopilot, so it takes their measured outcome on the autopilot the
schedule is for (`EventSchedule.autopilot`, ArduCopter unless told; docs/CONFORMANCE.md):
a UAV with a failed motor falls and is lost at once on both. A GPS loss differs:
- ArduCopter 4.7: a UAV whose GPS stays dark for GPS_FAILSAFE_S has its EKF failsafe
  switch it to LAND, out of the mission for good; a shorter loss is bridged by dead
  reckoning and changes nothing.
- PX4 1.17 (SIH): nothing takes the UAV out. An acceleration-only OFFBOARD needs only an
  attitude (commander's offboardCheck.cpp), so the vehicle stays in OFFBOARD under its
  agent, and its position stream goes on, dead-reckoned (the estimate drifts: 26 m off
  after 40 s, measured).
`fault_failures_at` gives both worlds the second each such UAV stops counting, and
`failure_s` includes it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from plmarl_sitl.mission import Event, Mission


def start_second(ev: Event) -> int:
    """The mission second `ev` starts at."""
    return math.ceil(ev.at_s)


def end_second(ev: Event) -> float:
    """The mission second `ev` is over at (inf: it lasts to the end of the mission)."""
    return math.ceil(ev.end_s()) if ev.duration_s is not None else math.inf


# Measured on ArduCopter 4.7 SITL (FS_EKF_ACTION 1, default EKF3 set-up), GPS gone in
# GUIDED flight: the EKF failsafe switches to LAND 8.1 s later, and the EKF stops aiding
# (LOCAL_POSITION_NED stops) 15.2 s later.
GPS_FAILSAFE_S = 8
GPS_AIDING_STOPS_S = 15
AUTOPILOT_FAULTS = ("gps_loss", "motor_failure")
# Seconds of GPS loss after which each autopilot's failsafe takes a UAV flying under its
# agent out of the mission (None: never, see above). Keyed by personality name.
GPS_OUT_AFTER_S: dict[str, int | None] = {"ardupilot": GPS_FAILSAFE_S, "px4": None}
# ... and after which its position stream stops (None: it goes on, dead-reckoned).
GPS_STREAM_STOPS_S: dict[str, int | None] = {"ardupilot": GPS_AIDING_STOPS_S, "px4": None}
FAULT_AUTOPILOTS = tuple(GPS_OUT_AFTER_S)


def fault_failure_second(ev: Event, autopilot: str = "ardupilot") -> float:
    """The mission second an autopilot fault takes its UAVs out of the mission (inf: never)
    on `autopilot` (a personality name)."""
    if ev.type == "motor_failure":
        return float(start_second(ev))
    out_s = GPS_OUT_AFTER_S[autopilot]
    if ev.type == "gps_loss" and out_s is not None and (ev.duration_s is None or end_second(ev) - start_second(ev) >= out_s):
        return float(start_second(ev) + out_s)
    return math.inf


@dataclass(frozen=True)
class Change:
    """`event` starts at mission second `second` (or, when `ends`, its duration runs out)."""

    second: int
    event: Event
    ends: bool = False


@dataclass(frozen=True)
class EventSchedule:
    n_uavs: int
    tup_s: int  # the mission's signalling interval, before any tup_change
    # Every event, node failures of the `failures` list included (first), in time order;
    # events at the same time keep the order they are written in.
    events: tuple[Event, ...]
    # Whose measured reaction to an autopilot fault the schedule applies (GPS_OUT_AFTER_S):
    # the SITL world's autopilots (`sitl.run_inputs`); the twin's default is ArduCopter's.
    autopilot: str = "ardupilot"

    def __post_init__(self) -> None:
        if self.autopilot not in GPS_OUT_AFTER_S:
            raise ValueError(f"no measured fault reactions for autopilot {self.autopilot!r} (have: {', '.join(GPS_OUT_AFTER_S)})")

    @classmethod
    def of(cls, mission: Mission, autopilot: str = "ardupilot") -> EventSchedule:
        failures = tuple(Event(type="node_failure", at_s=f.at_s, uav=f.uav) for f in mission.failures)
        events = tuple(sorted(failures + mission.events, key=lambda e: e.at_s))
        return cls(mission.n_uavs, mission.signalling.tup_s, events, autopilot)

    def has(self, kind: str) -> bool:
        return any(e.type == kind for e in self.events)

    def uavs_of(self, ev: Event) -> tuple[int, ...]:
        """The UAVs an event touches: `uav`, else its `uavs`, or all when empty."""
        if ev.uav is not None:
            return (ev.uav,)
        return ev.uavs or tuple(range(self.n_uavs))

    def fault_failures_at(self, second: int) -> list[tuple[int, Event]]:
        """(uav, fault) for each UAV an autopilot fault takes out of the mission at `second`."""
        return [(u, e) for e in self.events if e.type in AUTOPILOT_FAULTS
                and fault_failure_second(e, self.autopilot) == second for u in self.uavs_of(e)]

    # ------------------------------------------------------------------ what changes at t
    def changes_at(self, second: int) -> list[Change]:
        """What starts at `second` (in schedule order), then what ends there."""
        starts = [Change(second, e) for e in self.events if start_second(e) == second]
        ends = [Change(second, e, ends=True) for e in self.events if end_second(e) == second]
        return starts + ends

    # ------------------------------------------------------------------ what is in force at t
    def active(self, kind: str, t: int) -> tuple[Event, ...]:
        """The events of `kind` in force at second t, in schedule order."""
        return tuple(e for e in self.events if e.type == kind and start_second(e) <= t < end_second(e))

    def failure_s(self) -> tuple[float, ...]:
        """Per UAV, the second it fails at (inf: never): a node failure, or the autopilot
        fault that takes it out (`fault_failure_second`); it is dead from then on."""
        at = [math.inf] * self.n_uavs
        for e in self.events:
            if e.type == "node_failure" and e.uav is not None:
                at[e.uav] = min(at[e.uav], start_second(e))
            elif e.type in AUTOPILOT_FAULTS:
                for u in self.uavs_of(e):
                    at[u] = min(at[u], fault_failure_second(e, self.autopilot))
        return tuple(float(s) for s in at)

    def tup_at(self, t: int) -> int:
        """The signalling interval in force at second t (the latest tup_change wins)."""
        tup = self.tup_s
        for e in self.events:
            if e.type == "tup_change" and e.tup_s is not None and start_second(e) <= t:
                tup = e.tup_s
        return tup

    def instant_tup(self, t: int) -> int:
        """The interval that decides whether second t is a signalling instant.

        A change counts from the second after its own, as in the SITL world and agent
        (`deploy/agent/clock.py::MissionClock.set_tup`: the change reaches the agents during
        its second, whose instant follows the interval before it). Second 0 is always an
        instant."""
        return self.tup_at(t - 1) if t > 0 else self.tup_s

    def broker_down(self, t: int) -> bool:
        return bool(self.active("broker_outage", t))

    def cut_off(self, t: int) -> frozenset[int]:
        """The UAVs whose every link a blackout cuts at second t."""
        return frozenset(u for e in self.active("link_blackout", t) for u in self.uavs_of(e))

    def gnss_std_m(self, t: int) -> tuple[float, ...]:
        """Per UAV, the standard deviation (m per axis) of its position noise at second t:
        independent noises of overlapping gnss_noise events add up in quadrature."""
        stds: list[list[float]] = [[] for _ in range(self.n_uavs)]
        for e in self.active("gnss_noise", t):
            for u in self.uavs_of(e):
                stds[u].append(float(e.std_m or 0.0))
        return tuple(math.hypot(*s) for s in stds)


def failure_times(
    schedule: EventSchedule, num_envs: int, gen: torch.Generator, failure_prob: float = 0.0, failure_at_s: float = 100.0
) -> torch.Tensor:
    """(num_envs, N) float64: the second each UAV of each episode fails at (inf: never).

    The mission's node failures in every episode, plus the twin's training curriculum: with
    probability `failure_prob` an episode also loses one UAV, drawn at random, at `failure_at_s`.
    """
    b, n = num_envs, schedule.n_uavs
    fail_at = torch.tensor(schedule.failure_s(), dtype=torch.float64).repeat(b, 1)
    if failure_prob > 0:
        hit = torch.rand(b, generator=gen) < failure_prob
        who = torch.randint(0, n, (b,), generator=gen)
        rows = torch.nonzero(hit).flatten()
        at = torch.tensor(float(math.ceil(failure_at_s)), dtype=torch.float64)
        fail_at[rows, who[rows]] = torch.minimum(fail_at[rows, who[rows]], at)
    return fail_at


__all__ = ["AUTOPILOT_FAULTS", "FAULT_AUTOPILOTS", "GPS_AIDING_STOPS_S", "GPS_FAILSAFE_S", "GPS_OUT_AFTER_S", "GPS_STREAM_STOPS_S", "Change", "EventSchedule", "end_second",
           "failure_times", "fault_failure_second", "start_second"]
