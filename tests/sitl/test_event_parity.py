"""The twin and the SITL rig derive the same mission events at the same seconds.

Both read one `EventSchedule`. For every shipped mission and a few constructed ones (every
event kind, overlaps, listing out of time order, fractional times), each second of the
episode is compared: who is dead, which sender-receiver pairs signalling delivers, and
whose reported position is noisy. Twin: a `CoverageEnv` stepping with zero acceleration.
SITL: a (not started) `SitlWorld` applying its events on its clock, plus the launcher's
`LauncherEvents` driving a broker gate. Positions are the twin's on both sides, so only
the events can make them differ.
"""

import dataclasses
from pathlib import Path

import pytest
import torch

from plmarl_sitl.mission import Event, Failure, Mission, load_mission
from plmarl_sitl.model.events import EventSchedule
from plmarl_sitl.model.signalling import is_signalling_instant
from plmarl_sitl.sitl.launcher import LauncherEvents
from plmarl_sitl.sitl.world import SitlWorld, WorldConfig
from plmarl_sitl.twin.env import CoverageEnv

ROOT = Path(__file__).resolve().parents[2]
BASE = load_mission(ROOT / "missions" / "paper_urban.yaml")


def _with(name: str, *events: dict, failures: tuple[Failure, ...] = ()) -> Mission:
    return dataclasses.replace(BASE, name=name, events=tuple(Event(**e) for e in events), failures=failures)


CONSTRUCTED = [
    _with(
        "every_kind",
        {"type": "link_blackout", "at_s": 30, "duration_s": 20, "uavs": (0,)},
        {"type": "gnss_noise", "at_s": 40, "std_m": 3.0, "duration_s": 30, "uavs": (1,)},
        {"type": "link_blackout", "at_s": 60, "duration_s": 10},
        {"type": "broker_outage", "at_s": 80, "duration_s": 15},
        {"type": "node_failure", "at_s": 100, "uav": 2},
        {"type": "tup_change", "at_s": 120, "tup_s": 10},
        {"type": "gnss_noise", "at_s": 170, "std_m": 2.0},
        failures=(Failure(at_s=150, uav=1),),
    ),
    _with(
        "overlaps_out_of_order",
        {"type": "tup_change", "at_s": 130, "tup_s": 5},
        {"type": "tup_change", "at_s": 20, "tup_s": 10},
        {"type": "gnss_noise", "at_s": 10, "std_m": 2.0},
        {"type": "gnss_noise", "at_s": 20, "std_m": 3.0, "duration_s": 10, "uavs": (0,)},
        {"type": "gnss_noise", "at_s": 30, "std_m": 1.0, "duration_s": 50, "uavs": (0, 3)},
        {"type": "link_blackout", "at_s": 55, "duration_s": 20, "uavs": (1,)},
        {"type": "link_blackout", "at_s": 50, "duration_s": 10},
        {"type": "broker_outage", "at_s": 90, "duration_s": 10},
        {"type": "broker_outage", "at_s": 95, "duration_s": 10},
        {"type": "node_failure", "at_s": 140, "uav": 3},
        failures=(Failure(at_s=150, uav=3), Failure(at_s=0, uav=0)),
    ),
    _with(
        "fractional",
        {"type": "link_blackout", "at_s": 20.5, "duration_s": 9.7, "uavs": (2,)},
        {"type": "gnss_noise", "at_s": 33.3, "std_m": 4.0, "duration_s": 0.4},
        {"type": "gnss_noise", "at_s": 40.2, "std_m": 4.0, "duration_s": 5.5, "uavs": (3,)},
        {"type": "node_failure", "at_s": 60.2, "uav": 1},
        {"type": "broker_outage", "at_s": 70.5, "duration_s": 3.2},
        {"type": "tup_change", "at_s": 80.5, "tup_s": 6},
    ),
]
SHIPPED = [load_mission(p) for p in sorted((ROOT / "missions").glob("*.yaml"))]


def _twin_seconds(mission: Mission) -> list[tuple]:
    """Per second: dead UAVs, delivered (receiver, sender) pairs, UAVs reporting noisy
    positions, and the true positions (N, 3)."""
    env = CoverageEnv(mission, 1, seed=0)
    out = []
    while True:
        dead = set(torch.nonzero(~env.alive[0]).flatten().tolist())
        delivered = set(map(tuple, torch.nonzero(env.holdings.t_rx[0] == env.t).tolist()))
        noisy = set(torch.nonzero((env.observe().ego[0, :, :3] != env.pos[0]).any(-1)).flatten().tolist())
        out.append((dead, delivered, noisy, env.pos[0].clone()))
        if env.done:
            return out
        env.physics_step(torch.zeros(1, env.n, 3))


class _Gate:
    """Stands in for the broker gate: remembers whether it is passing traffic."""

    def __init__(self) -> None:
        self.down = False

    def outage(self, on: bool) -> None:
        self.down = on


class _Fleet:
    """Stands in for the agent fleet: which agents the launcher killed."""

    def __init__(self, n: int) -> None:
        self.procs = dict.fromkeys(range(n))
        self.killed: list[int] = []

    def kill(self, i: int) -> None:
        self.killed.append(i)

    def retire(self, i: int) -> None:  # an autopilot fault took its UAV out: the agent is asked to stop
        self.killed.append(i)


def _sitl_seconds(mission: Mission, positions: list[torch.Tensor]) -> list[tuple]:
    """Per second, as `_twin_seconds` (without positions), signalling from `positions`."""
    schedule = EventSchedule.of(mission)
    world = SitlWorld(WorldConfig(mission, "mqtt://127.0.0.1:1", events=schedule))
    gate, fleet, log = _Gate(), _Fleet(world.n), []
    LauncherEvents(world.events, fleet, gate, log.append)  # type: ignore[arg-type]  # registers on the world's dispatcher
    out = []
    for t, pos in enumerate(positions):
        if t > 0:
            world.host.advance(1.0)  # mission second t is boot second t here (t0 = 0)
        tup = world.tup_s  # the instant of second t follows T_up before its events (LockstepPacer._instant_tup)
        world.events.dispatch(t)  # what SitlWorld does at every mission second: its handlers, then the launcher's
        alive = world.alive()
        dead = {i for i in range(world.n) if not alive[i]}
        assert set(fleet.killed) == dead  # the agent goes with its vehicle
        delivered = set()
        if is_signalling_instant(t, tup) and not gate.down:
            for j in range(world.n):
                if alive[j]:
                    delivered |= {(i, j) for i in world.links.receivers(j, pos, alive, world.host.now)}
        noisy = {i for i, v in enumerate(world.host.vehicles) if v.nav_position() != v.position()}
        out.append((dead, delivered, noisy))
    return out


@pytest.mark.parametrize("mission", SHIPPED + CONSTRUCTED, ids=lambda m: m.name)
def test_twin_and_sitl_apply_the_same_events_at_the_same_seconds(mission):
    twin = _twin_seconds(mission)
    sitl = _sitl_seconds(mission, [pos for *_, pos in twin])
    assert len(sitl) == mission.timing.episode_s + 1
    for t, ((dead, delivered, noisy, _), (s_dead, s_delivered, s_noisy)) in enumerate(zip(twin, sitl, strict=True)):
        assert (dead, delivered, noisy) == (s_dead, s_delivered, s_noisy), f"{mission.name} at t = {t}"


def test_every_event_kind_takes_effect_in_the_constructed_mission():
    """The comparison above is not vacuous: each kind changes something in both worlds."""
    m = CONSTRUCTED[0]
    twin = _twin_seconds(m)
    dead, delivered, noisy = zip(*[(d, p, n) for d, p, n, _ in twin], strict=True)
    everyone = delivered[15]  # the pairs in range on the launch line
    assert {0, 1, 2, 3} <= {u for pair in everyone for u in pair}
    assert delivered[30] == {p for p in everyone if 0 not in p}  # uav 0 blacked out
    assert delivered[60] == set() and delivered[75] == everyone  # all links cut, then back
    # Broker down, then up (uav 2 failed at 100: less interference, more pairs hear each other).
    assert delivered[90] == set() and delivered[105] >= {p for p in everyone if 2 not in p}
    assert not any(2 in p for p in delivered[105])
    assert delivered[130] and not delivered[135]  # T_up 10 from 120: 130 is an instant, 135 no more
    assert noisy[40] == {1} and noisy[70] == set() and noisy[170] == {0, 1, 2, 3}
    assert dead[99] == set() and dead[100] == {2} and dead[150] == {1, 2}
