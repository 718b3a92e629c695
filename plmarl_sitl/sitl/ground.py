"""The SITL world's ground truth: the users, what the UAVs cover and sense, the demand map.

All of it is the twin's code on the true mission-frame positions, so the same seed gives
the same users as `CoverageEnv(mission, 1, seed)`:

* users step once per mission second (`model.users.step_users`, the twin's generator use);
* coverage C(t) (`covered_np`: `model.coverage.covered_users`' operations in one pass) and
  lambda_2 of the link graph;
* each vehicle's sensed users (within R_s of its true position) go to `sense/<id>`;
* the user-density map (`model.demand.demand_map`) goes to the retained `demand` topic for
  every map instant (`model.demand.is_map_instant`: where the twin refreshes its map).
  The twin's agents see the map of instant k at k, with no delay; a broker has one
  (seconds of vehicle time with the in-process amqtt on a loaded machine). The users'
  motion does not depend on the UAVs, so the users are stepped one map period ahead and
  the map of instant k goes out at k - period (map 0 with the start announcement): it is
  at the agents long before their decision at k, which never uses a map of a later
  instant (and still waits, bounded, for a late one).
"""

from __future__ import annotations

import collections
from dataclasses import dataclass

import numpy as np
import torch

from plmarl_sitl.deploy.mqtt.schema import Topics
from plmarl_sitl.deploy.mqtt.wire import Wire
from plmarl_sitl.mission import Mission
from plmarl_sitl.model.channel import CoverageRadius
from plmarl_sitl.model.demand import demand_map, grid_shape, is_map_instant, map_period
from plmarl_sitl.model.graph import algebraic_connectivity, link_mask, weighted_adjacency
from plmarl_sitl.model.users import UserState, init_users, step_users
from plmarl_sitl.sitl.outbox import Outbox


@dataclass(frozen=True)
class Measure:
    """One second's truth: coverage C(t), lambda_2 and the links up."""

    coverage: float
    lambda2: float
    links_up: int


class Ground:
    def __init__(self, mission: Mission, seed: int, outbox: Outbox, wire: Wire, topics: Topics,
                 publish_sense: bool = True) -> None:
        m = self.mission = mission
        vm = m.vehicle_model()
        self.radius = CoverageRadius(m.channel, m.radii.sensing_m, vm.min_alt_m, vm.max_alt_m)
        self.outbox, self.wire, self.topics = outbox, wire, topics
        self.publish_sense = publish_sense  # False: a vehicle without the sensor
        self.gen = torch.Generator().manual_seed(seed)  # as CoverageEnv(mission, 1, seed)
        self.users: UserState = init_users(m, 1, self.gen, torch.float32)
        self.users_ahead: collections.deque[UserState] = collections.deque()  # users of seconds k + 1 .. k + map period
        self.map_seq = 0

    def step_to(self, k: int) -> None:
        """The users at mission second k (stepped earlier), and the seconds ahead up to one
        map period: a map instant among them has its map published now. One step per
        second, in order: the generator is used as in the twin."""
        m = self.mission
        if k >= 1:
            self.users = self.users_ahead.popleft()
        period = map_period(m.demand.refresh_s, m.timing.decision_every_s)
        while len(self.users_ahead) < period:
            last = self.users_ahead[-1] if self.users_ahead else self.users
            self.users_ahead.append(step_users(last, m, m.timing.dt_s, self.gen))
            t = k + len(self.users_ahead)
            if is_map_instant(t, m.demand.refresh_s, m.timing.decision_every_s):
                self.publish_map(t, self.users_ahead[-1])

    def publish_map(self, k: int, users: UserState) -> None:
        """The user-density map of mission second k (users at k) on the retained demand topic."""
        m = self.mission
        counts = demand_map(users.xy[0], m.area.north_m, m.area.east_m, m.demand.cell_m)
        rows, cols = grid_shape(m.area.north_m, m.area.east_m, m.demand.cell_m)
        payload = self.wire.demand(self.map_seq, k * 1000, m.demand.cell_m, rows, cols, counts.round().long().tolist())
        self.outbox.publish_retained(self.topics.demand, payload)
        self.map_seq += 1

    def publish_start_map(self) -> None:
        """Map 0, with the start announcement: the users stay at their t = 0 positions until t0."""
        self.publish_map(0, self.users)

    def measure(self, pos: torch.Tensor, alive: torch.Tensor) -> Measure:
        """Coverage and lambda_2 now, on (N, 3) float32 mission-frame positions."""
        m = self.mission
        users = self.users.xy[0]  # (U, 2)
        # the mean is torch's, as the twin's: numpy's float32 sum need not add in the same order
        cov = float(torch.from_numpy(covered_np(users, pos, alive, self.radius(-pos[:, 2]))).float().mean())
        rx, sinr = link_mask(pos, alive, m.channel, m.radii.comm_m)
        lam2 = float(algebraic_connectivity(weighted_adjacency(rx, sinr), alive))
        return Measure(cov, lam2, int(rx.sum()))

    def sense(self, k: int, pos: torch.Tensor, alive: torch.Tensor) -> None:
        """Each live vehicle's sensed users at mission second k, to `sense/<id>` (none in an
        emulated outage)."""
        if not self.publish_sense or self.outbox.cut:
            return
        t_ms = k * 1000
        for i, inside in enumerate(sensed_users(self.users.xy[0], pos, alive, self.mission.radii.sensing_m)):
            if inside is not None:
                self.outbox.publish(self.topics.sense(i), self.wire.sense(i, t_ms, inside))


def sensed_users(users: torch.Tensor, pos: torch.Tensor, alive: torch.Tensor, radius_m: float) -> list[list | None]:
    """Per vehicle, the users (U, 2) float32 within `radius_m` of its (N, 3) float32
    position, as [[x, y], ...] (None for a dead vehicle): all vehicles in one numpy pass.
    The same float32 operations as the twin's per-vehicle torch test (squared distance
    d_x^2 + d_y^2, compared with R_s^2 rounded to float32), so the same users, bit for
    bit, at a fraction of twenty vehicles' torch calls per second."""
    u = users.numpy()
    p = pos.numpy()
    dx = u[:, 0][None, :] - p[:, 0:1]  # (N, U), contiguous rows
    dy = u[:, 1][None, :] - p[:, 1:2]
    near = dx * dx + dy * dy <= np.float32(radius_m**2)
    return [u[near[i]].tolist() if a else None for i, a in enumerate(alive.tolist())]


def covered_np(users: torch.Tensor, pos: torch.Tensor, alive: torch.Tensor, radius: torch.Tensor) -> np.ndarray:
    """`model.coverage.covered_users` for one swarm, (U,) bool, in one numpy pass over the
    (N, U) squared distances instead of its five torch calls per vehicle: the same float32
    operations (user minus UAV, d_n^2 + d_e^2, compared with r^2 or -1 for a dead UAV), so
    the same users, bit for bit (tests/sitl/test_ground_sense.py)."""
    u = users.numpy()
    p = pos.numpy()
    r2 = torch.where(alive, radius * radius, torch.full_like(radius, -1.0)).numpy()
    dn = u[:, 0][None, :] - p[:, 0:1]  # (N, U)
    de = u[:, 1][None, :] - p[:, 1:2]
    return (dn * dn + de * de <= r2[:, None]).any(0)
