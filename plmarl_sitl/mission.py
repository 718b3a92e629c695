"""Mission schema: the scenario every part of the toolkit runs (twin, trainer, SITL).

Units are SI; positions are metres in the mission frame, whose origin is the south-west
corner of the area with x north and y east (NED, altitude positive up where it says `alt`).
"""

from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from plmarl_sitl.config import MAX_SEED, ConfigError, VehicleModel, _require, from_dict, load_vehicle, read_yaml

MAX_DEMAND_CELLS = 65535  # the demand message's cell index is a u16 (docs/SIGNALLING.md)
# A swarm is at most 250 UAVs: MAVLink's 8-bit system ids (1..250 for vehicles; PX4's
# MAV_SYS_ID range, 255 is a ground station) name one vehicle each, and the gossiped failed
# set is a bitmask over them. Checked at load, before a key or a login file is written.
MAX_UAVS = 250
MAX_EPISODE_S = 86_400  # one day of mission time: far beyond any battery, and a bound on every per-second table

Mobility = Literal["gauss_markov", "random_waypoint", "rpgm", "mixed"]
Layout = Literal["fixed", "lattice", "random"]
# How an agent gets its plan point: the whole team's plan in every agent (model/service.py), or a
# plan of its own neighbourhood whose cost does not grow with N or the area (model/local_plan.py).
Coordination = Literal["team", "local"]
# How the team plan places its points (model/placement.py, issue 24.3): the greedy, the greedy
# from several starts with local improvement (`search`), or a greedy whose picks a learnt scorer
# ranks (`learned`, policies/pl-marl/placement.pt).
Placement = Literal["greedy", "search", "learned"]
# How a survivor's copy of the team plan changes when it learns that teammates failed
# (model/service.py::TeamPlans.replan): the whole plan re-solved for the survivors, or the first
# plan mended, each failed UAV's point by its own neighbours (model/repairs.py).
FailureReplan = Literal["resolve", "local"]


@dataclass(frozen=True)
class Area:
    north_m: float = field(default=1000.0, metadata={"min": 100.0})
    east_m: float = field(default=1000.0, metadata={"min": 100.0})


@dataclass(frozen=True)
class Users:
    count: int = field(default=240, metadata={"min": 1})
    cluster_size: int = field(default=60, metadata={"min": 1})
    mobility: Mobility = "gauss_markov"
    max_speed_mps: float = field(default=0.5, metadata={"min": 0.0})
    cluster_std_m: float = field(default=35.0, metadata={"min": 0.0})
    # Gauss-Markov memory per second (1 = straight lines, 0 = white noise).
    gm_alpha: float = field(default=0.95, metadata={"min": 0.0, "max": 1.0})
    layout: Layout = "fixed"
    # `fixed`: one (north, east) centre per cluster. `lattice`: spacing of a centred grid.
    cluster_centers: tuple[tuple[float, float], ...] = ()
    cluster_spacing_m: float = field(default=300.0, metadata={"min": 1.0})
    # RPGM: radius around its cluster's home within which a group's reference point picks its
    # waypoints (clamped into the area). 0: the default, 2 cluster_std_m (70 m on the paper
    # map). A wide range with a fast max_speed_mps makes crowds that walk across the area
    # (issue 24.3, moving demand).
    rpgm_range_m: float = field(default=0.0, metadata={"min": 0.0})

    @property
    def n_clusters(self) -> int:
        return self.count // self.cluster_size

    def __post_init__(self) -> None:
        _require(self.count % self.cluster_size == 0, "count", "must be a multiple of cluster_size")
        _require(
            self.layout == "fixed" or not self.cluster_centers,
            "cluster_centers",
            "only used with layout 'fixed' (remove it or set layout: fixed)",
        )
        if self.layout == "fixed":
            _require(
                len(self.cluster_centers) == self.n_clusters,
                "cluster_centers",
                f"layout 'fixed' needs {self.n_clusters} centres (count / cluster_size), "
                f"got {len(self.cluster_centers)}",
            )


@dataclass(frozen=True)
class Channel:
    """Air-to-ground (Al-Hourani) and UAV-to-UAV link parameters."""

    environment: str = "urban"
    los_a: float = 9.61
    los_b: float = 0.16
    eta_los_db: float = 1.0
    eta_nlos_db: float = 20.0
    carrier_ghz: float = field(default=2.0, metadata={"min": 0.01})
    # A user is covered when it is inside the sensing radius AND the mean A2G path loss
    # to it is at most this (docs/ARCHITECTURE.md, "Coverage").
    max_path_loss_db: float = 84.0
    u2u_carrier_ghz: float = field(default=2.4, metadata={"min": 0.01})
    tx_power_dbm: float = 20.0
    noise_dbm: float = -90.0
    # Mean share of time another UAV transmits in the same slot (co-channel interference).
    interference_activity: float = field(default=0.1, metadata={"min": 0.0, "max": 1.0})
    sinr_threshold_db: float = 0.0


@dataclass(frozen=True)
class Radii:
    sensing_m: float = field(default=100.0, metadata={"min": 1.0})
    comm_m: float = field(default=350.0, metadata={"min": 1.0})
    safe_m: float = field(default=20.0, metadata={"min": 0.0})


@dataclass(frozen=True)
class Signalling:
    tup_s: int = field(default=15, metadata={"min": 1})
    buffer_len: int = field(default=10, metadata={"min": 1})
    # A neighbour silent for this many consecutive signalling instants leaves N_i.
    drop_after_missed: int = field(default=2, metadata={"min": 1})


@dataclass(frozen=True)
class Demand:
    """The coarse user-density map the ground network publishes (plmarl_sitl/model/demand.py):
    user counts on square cells of `cell_m` over the area, refreshed every `refresh_s`.

    50 m, not 100: clusters 200 m apart on 100 m cells fill every cell alike (a cluster on a
    cell border splits evenly), so the team plan could not see where they are; measured on
    training-range draws of 20 clusters, its points served 0.80 of the users at 100 m and
    0.92 at 50 m (docs/RESULTS.md)."""

    cell_m: float = field(default=50.0, metadata={"min": 1.0})
    refresh_s: int = field(default=30, metadata={"min": 1})


@dataclass(frozen=True)
class Timing:
    dt_s: float = field(default=1.0, metadata={"min": 0.001})
    decision_every_s: int = field(default=3, metadata={"min": 1})
    episode_s: int = field(default=200, metadata={"min": 1, "max": MAX_EPISODE_S})


@dataclass(frozen=True)
class RewardWeights:
    coverage: float = 50.0
    potential: float = 0.5
    mobility: float = 2e-5
    safety: float = 1.0


@dataclass(frozen=True)
class Reward:
    pre_failure: RewardWeights = RewardWeights()
    post_failure: RewardWeights = RewardWeights(50.0, 2.0, 1e-5, 1.0)


@dataclass(frozen=True)
class Failure:
    at_s: float = field(metadata={"min": 0.0})
    uav: int = field(metadata={"min": 0})


EventType = Literal["node_failure", "link_blackout", "broker_outage", "tup_change", "gnss_noise", "gps_loss", "motor_failure"]

# Which optional fields each event type takes, and which it requires.
_EVENT_FIELDS: dict[str, tuple[set[str], set[str]]] = {
    "node_failure": ({"uav"}, {"uav"}),
    "link_blackout": ({"duration_s", "uavs"}, {"duration_s"}),
    "broker_outage": ({"duration_s"}, {"duration_s"}),
    "tup_change": ({"tup_s"}, {"tup_s"}),
    "gnss_noise": ({"std_m", "duration_s", "uavs"}, {"std_m"}),
    "gps_loss": ({"duration_s", "uavs"}, set()),
    "motor_failure": ({"uav"}, {"uav"}),
}


@dataclass(frozen=True)
class Event:
    """A scripted mission event on the sim clock.

    node_failure: vehicle `uav` stops and its agent is killed.
    link_blackout: links touching `uavs` (all links when empty) are cut for `duration_s`.
    broker_outage: the MQTT broker stops for `duration_s`, then restarts.
    tup_change: the signalling interval becomes `tup_s`.
    gnss_noise: position telemetry of `uavs` (all when empty) gets Gaussian noise of
    `std_m` per axis, for `duration_s` (to the end when omitted).

    Autopilot faults (the autopilot's own fault injection; docs/SIGNALLING.md, "Mission events"):
    gps_loss: the GPS receiver of `uavs` (all when empty) goes dark for `duration_s` (to the
    end when omitted). A real ArduCopter dead-reckons, then its EKF failsafe lands it.
    motor_failure: one motor of vehicle `uav` stops for good; a quadrotor falls.
    """

    type: EventType
    at_s: float = field(metadata={"min": 0.0})
    uav: int | None = field(default=None, metadata={"min": 0})
    uavs: tuple[int, ...] = ()
    duration_s: float | None = field(default=None, metadata={"min": 1e-9})
    tup_s: int | None = field(default=None, metadata={"min": 1})
    std_m: float | None = field(default=None, metadata={"min": 0.0})

    def __post_init__(self) -> None:
        allowed, required = _EVENT_FIELDS[self.type]
        for name in ("uav", "uavs", "duration_s", "tup_s", "std_m"):
            given = getattr(self, name) not in (None, ())
            _require(not given or name in allowed, name, f"not used by a {self.type} event")
            _require(given or name not in required, name, f"is required for a {self.type} event")

    def end_s(self) -> float:
        return self.at_s + self.duration_s if self.duration_s is not None else float("inf")


@dataclass(frozen=True)
class Launch:
    """Where the swarm starts: a line of UAVs at takeoff altitude centred on this point, UAV 0
    at one end, running along the compass bearing `bearing_deg` (90: west to east)."""

    north_m: float = 500.0
    east_m: float = 500.0
    spacing_m: float = field(default=40.0, metadata={"min": 0.0})
    bearing_deg: float = field(default=90.0, metadata={"min": 0.0, "max": 360.0})

    def direction(self) -> tuple[float, float]:
        """Unit (north, east) step from one UAV of the line to the next. Rounded so that the
        compass points are exact: bearing 90 gives (0, 1), the line every mission had before
        the bearing was a field, to the last bit."""
        b = math.radians(self.bearing_deg)
        return round(math.cos(b), 15) + 0.0, round(math.sin(b), 15) + 0.0


@dataclass(frozen=True)
class Origin:
    """Geodetic position of the mission frame's origin (for GLOBAL_POSITION_INT)."""

    lat_deg: float = field(default=47.397742, metadata={"min": -90.0, "max": 90.0})
    lon_deg: float = field(default=8.545594, metadata={"min": -180.0, "max": 180.0})
    alt_m: float = 488.0


@dataclass(frozen=True)
class Mission:
    name: str
    seed: int = field(default=0, metadata={"min": 0, "max": MAX_SEED})
    n_uavs: int = field(default=4, metadata={"min": 1, "max": MAX_UAVS})
    vehicle: str = "quadrotor"
    area: Area = Area()
    users: Users = Users(layout="lattice")
    channel: Channel = Channel()
    radii: Radii = Radii()
    signalling: Signalling = Signalling()
    demand: Demand = Demand()
    timing: Timing = Timing()
    reward: Reward = Reward()
    launch: Launch = Launch()
    origin: Origin = Origin()
    # Node failures, shorthand for node_failure events (the twin's and the trainer's form;
    # `model.events.EventSchedule` puts both on one clock).
    failures: tuple[Failure, ...] = ()
    events: tuple[Event, ...] = ()
    coordination: Coordination = "team"
    placement: Placement = "search"
    failure_replan: FailureReplan = "local"  # on station; a failure in transit is re-solved (model/repairs.py)
    # Metres a UAV's plan point moves toward the centroid of the users it senses
    # (model/sensed_track.py: follow a moving crowd between demand maps); 0: off.
    track_sensed_m: float = field(default=0.0, metadata={"min": 0.0})
    # Metres from its plan point beyond which a learnt policy's UAV flies the plan follower's
    # command, the motion its teammates predict it by (model/plan_follower.py); 0: the policy everywhere.
    transit_plan_m: float = field(default=0.0, metadata={"min": 0.0})

    def __post_init__(self) -> None:
        for i, ev in enumerate(self.events):
            ids = ((ev.uav,) if ev.uav is not None else ()) + ev.uavs
            for u in ids:
                _require(u < self.n_uavs, f"events[{i}].{'uav' if ev.uav is not None else 'uavs'}", f"must be < n_uavs ({self.n_uavs})")
            _require(ev.at_s <= self.timing.episode_s, f"events[{i}].at_s", f"must be <= timing.episode_s ({self.timing.episode_s})")
        for i, f in enumerate(self.failures):
            _require(f.uav < self.n_uavs, f"failures[{i}].uav", f"must be < n_uavs ({self.n_uavs})")
            _require(
                f.at_s <= self.timing.episode_s,
                f"failures[{i}].at_s",
                f"must be <= timing.episode_s ({self.timing.episode_s})",
            )
        cells = math.ceil(self.area.north_m / self.demand.cell_m - 1e-9) * math.ceil(self.area.east_m / self.demand.cell_m - 1e-9)
        _require(cells <= MAX_DEMAND_CELLS, "demand.cell_m",
                 f"too small for the area: {cells} cells, the demand message indexes at most {MAX_DEMAND_CELLS}")
        centres = self.users.cluster_centers if self.users.layout == "fixed" else ()
        for i, (n, e) in enumerate(centres):
            ok = 0 <= n <= self.area.north_m and 0 <= e <= self.area.east_m
            _require(ok, f"users.cluster_centers[{i}]", "must lie inside the area")

    def reach_warnings(self) -> list[str]:
        """What the schema accepts but a user should hear: fixed clusters that fall apart into
        groups more than R_comm from each other (one UAV per cluster cannot stay connected)."""
        centres = self.users.cluster_centers if self.users.layout == "fixed" else ()
        group = list(range(len(centres)))  # union-find over "within R_comm"

        def root(i: int) -> int:
            while group[i] != i:
                group[i] = group[group[i]]
                i = group[i]
            return i

        for i, a in enumerate(centres):
            for j in range(i):
                if math.dist(a, centres[j]) <= self.radii.comm_m:
                    group[root(i)] = root(j)
        parts: dict[int, list[int]] = {}
        for i in range(len(centres)):
            parts.setdefault(root(i), []).append(i)
        if len(parts) < 2:
            return []
        listed = "; ".join(", ".join(map(str, p)) for p in parts.values())
        return [f"users.cluster_centers: the clusters fall into {len(parts)} groups more than R_comm "
                f"({self.radii.comm_m:g} m) apart ({listed}): a swarm with one UAV per cluster cannot stay connected"]

    def vehicle_model(self) -> VehicleModel:
        return load_vehicle(self.vehicle)

    def with_coordination(self, coordination: str) -> Mission:
        return dataclasses.replace(self, coordination=coordination)

    def with_placement(self, placement: str) -> Mission:
        return dataclasses.replace(self, placement=placement)

    def with_failure_replan(self, how: str) -> Mission:
        return dataclasses.replace(self, failure_replan=how)

    def with_track_sensed(self, metres: float) -> Mission:
        return dataclasses.replace(self, track_sensed_m=float(metres))

    def with_transit_plan(self, metres: float) -> Mission:
        return dataclasses.replace(self, transit_plan_m=float(metres))

    def with_tup(self, tup_s: int) -> Mission:
        return dataclasses.replace(self, signalling=dataclasses.replace(self.signalling, tup_s=tup_s))


def _deep_merge(base: dict, over: dict) -> dict:
    out = dict(base)
    for k, v in over.items():
        out[k] = _deep_merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def _read_mission_data(path: Path, seen: tuple[Path, ...] = ()) -> dict:
    """The mission's plain data, with `extends: other.yaml` (relative to this file)
    resolved: this file's keys override the other's, mappings merged key by key."""
    if path.resolve() in seen:
        raise ConfigError("extends", "missions extend each other in a cycle", str(path))
    data = read_yaml(path)
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError("", "expected a mapping at the top level", str(path))
    base = data.pop("extends", None)
    if base is None:
        return data
    if not isinstance(base, str):
        raise ConfigError("extends", "expected a file name", str(path))
    target = path.parent / base
    if not target.is_file():  # named from the file that says `extends`, which is the one to fix
        raise ConfigError("extends", f"no mission file {target}", str(path))
    return _deep_merge(_read_mission_data(target, (*seen, path.resolve())), data)


def mission_from_dict(data: dict, source: str | None = None) -> Mission:
    try:
        return from_dict(Mission, data)
    except ConfigError as exc:
        raise ConfigError(exc.path, exc.reason, source) from None


def load_mission(path: str | Path, *, warn: bool = True) -> Mission:
    """Load a mission YAML; errors are ConfigError naming the file and the key path. `warn`: log
    what the schema accepts but a user should hear (`reach_warnings`); the suite's own missions,
    whose gaps are the point of their family, load without."""
    path = Path(path)
    mission = mission_from_dict(_read_mission_data(path), str(path))
    for warning in mission.reach_warnings() if warn else ():
        logging.getLogger("plmarl.mission").warning("%s: warning: %s", path, warning)
    try:
        mission.vehicle_model()
    except ConfigError as exc:
        raise ConfigError("vehicle", f"cannot load vehicle model {mission.vehicle!r}: {exc}", str(path)) from None
    return mission
