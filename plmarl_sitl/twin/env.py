"""The digital twin: a batch of synchronous coverage episodes on torch tensors.

Timing follows the paper: physics, users, signalling and coverage advance in steps of
`timing.dt_s` (1 s); `step()` is one *decision* and holds the commanded accelerations for
`timing.decision_every_s` physics steps (tau = 3); an episode is `timing.episode_s`
physics steps. All environments share the clock, so `t` is a plain int.

What an agent observes (`Observation`) is exactly what a deployed agent has: its own
true state, what it last received from each neighbour at a signalling instant (with the
P-AoI), and the users its own sensor sees within R_s. The centralised critic gets
`global_state()`. Learners turn held states into beliefs themselves (plmarl_sitl.learning.nn).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import torch

from plmarl_sitl.mission import Mission
from plmarl_sitl.model.channel import CoverageRadius
from plmarl_sitl.model.coverage import SENSING_FEATURES, covered_users, sensing_features
from plmarl_sitl.model.demand import cell_centres, demand_cells, demand_map
from plmarl_sitl.model.events import EventSchedule, failure_times
from plmarl_sitl.model.gossip import Gossip
from plmarl_sitl.model.graph import algebraic_connectivity, link_mask, weighted_adjacency
from plmarl_sitl.model.reward import RewardTerms, combine, reward_terms
from plmarl_sitl.model.signalling import Holdings, is_signalling_instant, signalling_update
from plmarl_sitl.model.users import UserState, init_users, step_users
from plmarl_sitl.model.vehicle import Limits, step_point_mass


@dataclass(frozen=True)
class Observation:
    """Per-agent local observations, physical units (metres, m/s, seconds)."""

    t: int
    ego: torch.Tensor  # (B, N, 6) own true [pos NED, vel NED]
    alive: torch.Tensor  # (B, N) bool
    nbr_state: torch.Tensor  # (B, N, N, 6) [i, j]: last state i received from j
    nbr_aoi: torch.Tensor  # (B, N, N) P-AoI of that state, seconds (>= 1)
    nbr_mask: torch.Tensor  # (B, N, N) bool: j in N_i (heard recently enough, alive i)
    nbr_t_rx: torch.Tensor  # (B, N, N) time the held state was received
    sense: torch.Tensor  # (B, N, SENSING_FEATURES) local user sensing
    fail_flag: torch.Tensor  # (B, N) bool: agent i has dropped a neighbour (raw; learners' f: silent_in_range)
    demand: torch.Tensor  # (B, K, 3) the published user-density map: [cell centre n, e, count]
    # Every agent's knowledge of failures (failed set, plan epoch), merged from the states it
    # received (model/gossip.py). The env's own object: a controller adds its agents'
    # declarations to it, and the next signalling instant sends them with the states.
    gossip: Gossip | None = None


@dataclass(frozen=True)
class StepInfo:
    coverage: torch.Tensor  # (B, k) C(t) after each physics step of the decision
    min_separation: torch.Tensor  # (B,) smallest live-pair distance seen, metres
    lambda2: torch.Tensor | None  # (B, k) when track_lambda2
    failed: torch.Tensor  # (B,) bool: global failure state f


def launch_positions(mission: Mission, alt_m: float) -> torch.Tensor:
    """(N, 3) NED start positions: a line through the launch point along its bearing, at `alt_m`."""
    n = mission.n_uavs
    la = mission.launch
    offs = (torch.arange(n, dtype=torch.float64) - (n - 1) / 2) * la.spacing_m
    d_north, d_east = la.direction()
    return torch.stack([la.north_m + offs * d_north, la.east_m + offs * d_east,
                        torch.full((n,), -alt_m, dtype=torch.float64)], -1)


def random_launch_positions(mission: Mission, batch: int, alt_m: float, gen: torch.Generator) -> torch.Tensor:
    """(B, N, 3) start lines with a random centre and orientation per environment (the
    training distribution of issue 12), the mission's spacing, inside the area."""
    n, spacing = mission.n_uavs, mission.launch.spacing_m
    half = (n - 1) / 2 * spacing
    margin = min(half + 50.0, 0.5 * min(mission.area.north_m, mission.area.east_m))
    u = torch.rand(batch, 3, generator=gen, dtype=torch.float64)
    centre_n = margin + u[:, 0] * (mission.area.north_m - 2 * margin)
    centre_e = margin + u[:, 1] * (mission.area.east_m - 2 * margin)
    heading = torch.pi * u[:, 2]  # direction of the line; 0 = along east, as the mission's launch
    offs = (torch.arange(n, dtype=torch.float64) - (n - 1) / 2) * spacing
    north = centre_n.unsqueeze(-1) + offs * torch.sin(heading).unsqueeze(-1)
    east = centre_e.unsqueeze(-1) + offs * torch.cos(heading).unsqueeze(-1)
    return torch.stack([north, east, torch.full_like(north, -alt_m)], -1)


class CoverageEnv:
    def __init__(
        self,
        mission: Mission,
        num_envs: int,
        seed: int,
        *,
        dtype: torch.dtype = torch.float32,
        device: str = "cpu",
        failure_prob: float = 0.0,
        failure_at_s: float = 100.0,
        track_lambda2: bool = False,
        random_launch: bool = False,
    ) -> None:
        self.mission = mission
        self.num_envs = num_envs
        self.n = mission.n_uavs
        self.dtype, self.device = dtype, device
        self.failure_prob, self.failure_at_s = failure_prob, failure_at_s
        self.track_lambda2 = track_lambda2
        self.random_launch = random_launch  # off: the mission's launch line in every environment
        self.gen = torch.Generator().manual_seed(seed)
        vm = mission.vehicle_model()
        self.vehicle = vm
        self.limits = Limits.band(vm)
        self.radius = CoverageRadius(mission.channel, mission.radii.sensing_m, vm.min_alt_m, vm.max_alt_m)
        self.t = 0
        self.reset()

    # ---------------------------------------------------------------- state access
    @property
    def horizon(self) -> int:
        return int(round(self.mission.timing.episode_s / self.mission.timing.dt_s))

    @property
    def done(self) -> bool:
        return self.t >= self.horizon

    def true_state(self) -> torch.Tensor:
        return torch.cat([self.pos, self.vel], -1)

    # ---------------------------------------------------------------- reset
    def reset(self) -> Observation:
        m, b, n = self.mission, self.num_envs, self.n
        alt = min(max(self.vehicle.takeoff_alt_m, self.limits.alt_min), self.limits.alt_max)
        if self.random_launch:
            self.pos = random_launch_positions(m, b, alt, self.gen).to(self.dtype).to(self.device)
        else:
            self.pos = launch_positions(m, alt).to(self.dtype).unsqueeze(0).repeat(b, 1, 1).to(self.device)
        self.vel = torch.zeros_like(self.pos)
        self.alive = torch.ones(b, n, dtype=torch.bool, device=self.device)
        self.users: UserState = init_users(m, b, self.gen, self.dtype, self.device)
        self.events = EventSchedule.of(m)
        self.fail_at = failure_times(self.events, b, self.gen, self.failure_prob, self.failure_at_s).to(self.device)
        self.holdings = Holdings.empty((b,), n, self.dtype, self.device)
        self.gossip = Gossip(b, n, self.device)
        self.t = 0
        self._apply_failures()
        self.run_signalling()
        self.covered = covered_users(self.users.xy, self.pos, self.alive, self.radius(-self.pos[..., 2]))
        self.demand_t = None
        return self.observe()

    # ---------------------------------------------------------------- dynamics
    def _apply_failures(self) -> None:
        dead = self.fail_at <= self.t
        if bool((dead & self.alive).any()):
            self.alive = self.alive & ~dead
            self.vel = torch.where(self.alive.unsqueeze(-1), self.vel, torch.zeros_like(self.vel))

    def run_signalling(self) -> None:
        """The signalling instant at the current second, if it is one: every UAV broadcasts
        its (navigation) state and what each neighbour hears goes into its holdings."""
        m, t = self.mission, self.t
        if not is_signalling_instant(t, self.events.instant_tup(t)):
            return
        rx, _ = link_mask(self.pos, self.alive, m.channel, m.radii.comm_m)
        if self.events.broker_down(t):
            rx = torch.zeros_like(rx)
        cut = self.events.cut_off(t)
        if cut:
            mask = self._selected(tuple(cut))
            rx = rx & ~(mask.unsqueeze(-1) | mask.unsqueeze(-2))
        sent = torch.cat([self._gnss(self.pos), self.vel], -1)
        self.holdings = signalling_update(self.holdings, float(t), rx, sent, m.signalling.drop_after_missed)
        self.gossip.receive(rx & ~torch.eye(self.n, dtype=torch.bool, device=self.device))  # each state brings its sender's knowledge

    def _selected(self, uavs: tuple[int, ...]) -> torch.Tensor:
        """(N,) bool mask of the listed UAVs."""
        mask = torch.zeros(self.n, dtype=torch.bool, device=self.device)
        mask[list(uavs)] = True
        return mask

    def _gnss(self, pos: torch.Tensor) -> torch.Tensor:
        """Positions as the UAVs' own navigation reports them (gnss_noise events): one
        draw per event in force, in schedule order."""
        for ev in self.events.active("gnss_noise", self.t):
            if ev.std_m:
                noise = ev.std_m * torch.randn(pos.shape, generator=self.gen, dtype=pos.dtype).to(pos.device)
                pos = pos + noise * self._selected(self.events.uavs_of(ev)).view(1, -1, 1)
        return pos

    def physics_step(self, accel: torch.Tensor) -> tuple[torch.Tensor, RewardTerms]:
        """One dt of everything; returns (reward (B,), its terms incl. coverage (B,))."""
        m = self.mission
        dt = m.timing.dt_s
        live = self.alive.unsqueeze(-1)
        accel = torch.where(live, accel.to(self.dtype), torch.zeros_like(self.pos))
        pos, vel = step_point_mass(self.pos, self.vel, accel, dt, self.limits)
        self.pos = torch.where(live, pos, self.pos)
        self.vel = torch.where(live, vel, torch.zeros_like(vel))
        self.users = step_users(self.users, m, dt, self.gen)
        self.t += 1
        self._apply_failures()
        self.covered = covered_users(self.users.xy, self.pos, self.alive, self.radius(-self.pos[..., 2]))
        coverage = self.covered.to(self.dtype).mean(-1)
        terms = reward_terms(coverage, self.pos, self.vel, self.alive, self.users.xy, m)
        self.run_signalling()
        return combine(terms, self.failed, m), terms

    @property
    def failed(self) -> torch.Tensor:
        return ~self.alive.all(-1)

    def step(self, accel: torch.Tensor) -> tuple[Observation, torch.Tensor, StepInfo]:
        """Hold `accel` (B, N, 3) m/s^2 NED for one decision interval.

        Returns the next observation, the mean per-second reward over the interval and
        per-step diagnostics. Dead agents' actions are ignored.
        """
        if self.done:
            raise RuntimeError("episode is over: call reset()")
        k = min(self.mission.timing.decision_every_s, self.horizon - self.t)
        rewards, covs, lams = [], [], []
        min_sep = torch.full((self.num_envs,), float("inf"), dtype=self.dtype, device=self.device)
        for _ in range(k):
            r, terms = self.physics_step(accel)
            rewards.append(r)
            covs.append(terms.coverage)
            min_sep = torch.minimum(min_sep, terms.min_separation)
            if self.track_lambda2:
                lams.append(self.lambda2())
        info = StepInfo(
            coverage=torch.stack(covs, -1),
            min_separation=min_sep,
            lambda2=torch.stack(lams, -1) if lams else None,
            failed=self.failed,
        )
        return self.observe(), torch.stack(rewards, -1).mean(-1), info

    def lambda2(self) -> torch.Tensor:
        rx, sinr = link_mask(self.pos, self.alive, self.mission.channel, self.mission.radii.comm_m)
        return algebraic_connectivity(weighted_adjacency(rx, sinr), self.alive).to(self.dtype)

    # ---------------------------------------------------------------- observations
    def published_demand(self) -> torch.Tensor:
        """(B, K, 3) the user-density map as last published: recomputed at t = 0 and then
        every `demand.refresh_s` seconds (observations come at decisions, so a refresh
        period that is a multiple of tau lands exactly)."""
        m = self.mission
        if self.demand_t is None or self.t - self.demand_t >= m.demand.refresh_s:
            counts = demand_map(self.users.xy, m.area.north_m, m.area.east_m, m.demand.cell_m)
            self.demand = demand_cells(counts, cell_centres(m.area.north_m, m.area.east_m, m.demand.cell_m, self.dtype))
            self.demand_t = self.t
        return self.demand

    def observe(self) -> Observation:
        m = self.mission
        h = self.holdings
        alive_rx = self.alive.unsqueeze(-1)
        mask = h.neighbour_mask(m.signalling.drop_after_missed) & alive_rx
        sense = sensing_features(self.pos, self.users.xy, m.radii.sensing_m, m.users.cluster_size)
        sense = torch.where(alive_rx, sense, torch.zeros_like(sense))
        return Observation(
            t=self.t,
            ego=torch.cat([self._gnss(self.pos), self.vel], -1),
            alive=self.alive,
            nbr_state=h.state,
            nbr_aoi=h.aoi(float(self.t)),
            nbr_mask=mask,
            nbr_t_rx=h.t_rx,
            sense=sense,
            fail_flag=h.lost & self.alive,
            demand=self.published_demand(),
            gossip=self.gossip,
        )

    def global_state(self) -> torch.Tensor:
        """(B, 7N + 3C + 3) for the centralised critic, every entry roughly in [-1, 1]:
        per UAV [north, east, alt, v (3), alive], per user cluster [centroid north/east,
        covered share], then [C(t), t / T, f]."""
        m, vm = self.mission, self.vehicle
        scale_p = torch.tensor([m.area.north_m, m.area.east_m, -vm.max_alt_m], dtype=self.dtype, device=self.device)
        uav = torch.cat([self.pos / scale_p, self.vel / vm.max_speed_mps, self.alive.to(self.dtype).unsqueeze(-1)], -1)
        c, size = m.users.n_clusters, m.users.cluster_size
        upos = self.users.pos.view(self.num_envs, 2, c, size).mean(-1).transpose(1, 2)
        upos = upos / torch.tensor([m.area.north_m, m.area.east_m], dtype=self.dtype, device=self.device)
        ucov = self.covered.view(self.num_envs, c, size).to(self.dtype).mean(-1, keepdim=True)
        tail = torch.stack(
            [self.covered.to(self.dtype).mean(-1), torch.full_like(self.covered[:, 0], self.t / self.horizon, dtype=self.dtype), self.failed.to(self.dtype)],
            -1,
        )
        return torch.cat([uav.flatten(1), torch.cat([upos, ucov], -1).flatten(1), tail], -1)

    def global_state_dim(self) -> int:
        return 7 * self.n + 3 * self.mission.users.n_clusters + 3

    def replace_mission(self, **changes: object) -> None:
        """For sweeps and curricula: change mission fields (e.g. signalling) for the next
        reset. Fields fixed at construction (n_uavs, vehicle, channel) must not change."""
        self.mission = dataclasses.replace(self.mission, **changes)


__all__ = ["CoverageEnv", "Observation", "StepInfo", "SENSING_FEATURES", "launch_positions", "random_launch_positions"]
