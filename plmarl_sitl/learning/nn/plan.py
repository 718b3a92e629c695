"""The team plan's targets for a batch of twin agents (model/service.py), from what each
agent observes: its own state and the states it received at the first signalling instant
(the launch line), and the published demand maps. The deployed agent runs the same
`TeamPlans` on its own messages (deploy/agent/plan.py)."""

from __future__ import annotations

import functools

import numpy as np
import torch

from plmarl_sitl.config import PROJECT_POLICIES
from plmarl_sitl.learning.nn.placement import load_placement_scorer
from plmarl_sitl.model.channel import mission_coverage
from plmarl_sitl.model.demand import map_period
from plmarl_sitl.model.events import EventSchedule
from plmarl_sitl.model.gossip import DECLARE_AFTER_MISSED, Gossip, heard, may_predict, steady, suspects
from plmarl_sitl.model.placement import LearnedPlacement, SearchPlacement
from plmarl_sitl.model.plan_follower import PlanFollower
from plmarl_sitl.model.plan_motion import PlanMotion
from plmarl_sitl.model.repairs import local_repairs
from plmarl_sitl.model.service import (
    Placer,
    Repairer,
    ServiceGrid,
    TeamPlans,
    grid_counts,
    launch_line,
    mission_launch_xy,
    plan_geometry,
)
from plmarl_sitl.model.vehicle import Limits

PLACEMENT_SCORER = PROJECT_POLICIES / "pl-marl" / "placement.pt"  # `placement: learned`'s scorer and its card


def heard_launch(ego_xy: np.ndarray, held_xy: np.ndarray, heard: np.ndarray, me: int,
                 nominal: np.ndarray | None = None) -> np.ndarray:
    """One agent's launch line (n, 2): itself at ego_xy (2,), the neighbours it heard at the
    first instant (heard (n,) bool) at held_xy (n, 2); nominal: the mission's line
    (`model/service.py::launch_line`)."""
    ids = [me] + [j for j in range(len(heard)) if heard[j] and j != me]
    pos = np.stack([ego_xy] + [held_xy[j] for j in ids[1:]])
    return launch_line(np.asarray(ids), pos, len(heard), nominal)


@functools.lru_cache(maxsize=8)
def _grid(area_n: float, area_e: float, cell_m: float, cover_r: float, comm_m: float, safe_m: float,
          placement: str = "greedy") -> ServiceGrid:
    return ServiceGrid(area_n, area_e, cell_m, cover_r, comm_m, safe_m, placer(placement))


def placer(placement: str) -> Placer | None:
    """The mission's `placement` (model/placement.py): None for the greedy."""
    if placement == "search":
        return SearchPlacement()
    if placement == "learned":
        return LearnedPlacement(load_placement_scorer(PLACEMENT_SCORER))
    return None


def service_grid(mission) -> ServiceGrid:  # noqa: ANN001 - Mission
    """The mission's plan grid, built once per set of constants and placement (it is a few MB
    of tables); the twin's plan and the deployed agent's both take it from here."""
    return _grid(*plan_geometry(mission), getattr(mission, "placement", "greedy"))


class SignallingInstants:
    """The mission's signalling instants (T_up changes included), as the twin's signalling."""

    def __init__(self, mission) -> None:  # noqa: ANN001 - Mission
        self.schedule = EventSchedule.of(mission)

    def is_instant(self, t: int) -> bool:
        return t % self.schedule.instant_tup(t) == 0

    def last(self, t: int) -> int:
        """The newest signalling instant not after second t."""
        while t > 0 and not self.is_instant(t):
            t -= 1
        return max(t, 0)

    def recent(self, t: int, k: int) -> list[int]:
        """The newest k signalling instants not after second t (fewer near t = 0)."""
        out = [self.last(t)]
        while len(out) < k and out[-1] > 0:
            out.append(self.last(out[-1] - 1))
        return out


def motion_of(mission, instants: SignallingInstants) -> PlanMotion:  # noqa: ANN001 - Mission
    """The plan-aware prediction of the mission's team: its vehicle's limits, the plan's
    altitude, the twin's take-off altitude, decisions every tau."""
    vm = mission.vehicle_model()
    limits = Limits.band(vm)
    alt, _ = mission_coverage(mission)
    start_alt = min(max(vm.takeoff_alt_m, limits.alt_min), limits.alt_max)
    return PlanMotion(limits, float(alt), float(start_alt), int(mission.timing.decision_every_s), instants.is_instant)


def repairer_of(mission) -> Repairer | None:  # noqa: ANN001 - Mission
    """How the mission's failure re-plans mend the plan (`failure_replan`): None re-solves it."""
    return local_repairs if mission.failure_replan == "local" else None


class ServiceTargets:
    """Per twin agent, the offset-free target (its plan point), (B, N, 2) metres.

    With the twin's `Gossip` (`update(..., gossip=obs.gossip)`) the plan also re-plans at
    failures (model/gossip.py, `TeamPlans.replan`): each agent declares failed a neighbour
    out of N_i that the plan-aware prediction puts in clear hearing at the instants it
    missed and whose last message knew the agent's declarations before then, and each copy
    settles its plan (`TeamPlans.settle`) whenever its agent's declarations (identity,
    instant) differ from the ones its plan was made for."""

    def __init__(self, mission, replan: bool = True, sources: str = "plan",  # noqa: ANN001 - Mission
                 declare_after: int = DECLARE_AFTER_MISSED) -> None:
        self.follower = PlanFollower(mission)
        self.grid = service_grid(mission)
        self.period = map_period(mission.demand.refresh_s, mission.timing.decision_every_s)
        self.comm_m = float(mission.radii.comm_m)
        self.channel = mission.channel
        self.declare_after = int(declare_after)  # missed instants before a declaration (model/gossip.py)
        self.replans = replan
        # Where a re-plan assigns from: "plan", the plan-aware prediction (common knowledge);
        # "cv", the ablation: each agent's own held states dead-reckoned at constant velocity.
        self.sources = sources
        self.instants = SignallingInstants(mission)
        self.mission = mission
        self.nominal = mission_launch_xy(mission)  # the mission's launch line (launch_line)
        self.reset()

    @classmethod
    def of(cls, mission, replan: bool = True, sources: str = "plan",  # noqa: ANN001, ANN206 - Mission; ServiceTargets | LocalTargets
           declare_after: int = DECLARE_AFTER_MISSED):
        """The mission's coordination: this team plan, or with `coordination: local` the
        neighbourhood plan (learning/nn/local_targets.py), which has the same interface."""
        if getattr(mission, "coordination", "team") == "local":
            from plmarl_sitl.learning.nn.local_targets import LocalTargets

            return LocalTargets(mission)
        return cls(mission, replan, sources, declare_after)

    def accel(self, ego: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        """Fly to the plan point `target` (..., 2) at the altitude of the largest coverage radius
        and stop there: the plan teacher of imitation, and `ServiceController`."""
        return self.follower.accel(ego, target)

    def copy_points(self) -> torch.Tensor | None:
        """(B, N, n, 2) float64: every identity's point in each agent's copy of the plan (NaN: failed);
        None before the plan starts. What bounds the sensed-users shift (model/sensed_track.py)."""
        return None if self.plans is None else torch.from_numpy(self.plans.all_targets())

    def reset(self) -> None:
        self.plans: TeamPlans | None = None
        self.map_t = -1
        self.last: torch.Tensor | None = None  # the targets of the last update
        self.replans_done = 0  # copies re-planned (for reports)

    def update(self, t: int, ego: torch.Tensor, nbr_state: torch.Tensor, nbr_t_rx: torch.Tensor,
               demand: torch.Tensor, *, mask: torch.Tensor | None = None, alive: torch.Tensor | None = None,
               gossip: Gossip | None = None) -> torch.Tensor:
        """Call at every decision: ego (B, N, 6), nbr_state (B, N, N, 6), nbr_t_rx (B, N, N), demand (B, K, 3).
        Re-planning at failures needs mask (B, N, N) N_i, alive (B, N) and the twin's gossip."""
        counts = np.stack([grid_counts(d, self.grid) for d in demand.double().numpy()])
        b, n = ego.shape[:2]
        if self.plans is None:
            ego_xy = ego[..., :2].double().numpy()
            held = nbr_state[..., :2].double().numpy()
            heard = (nbr_t_rx == float(t)).numpy()
            launch = np.stack([np.stack([heard_launch(ego_xy[e, i], held[e, i], heard[e, i], i, self.nominal) for i in range(n)])
                               for e in range(b)])
            # The plan-aware prediction only where failures can be learnt (the twin's gossip given):
            # training's plan teacher calls without and does not pay for it.
            motion = motion_of(self.mission, self.instants) if self.replans and gossip is not None else None
            self.plans = TeamPlans(self.grid, n, motion, repairer_of(self.mission))
            self.plans.start(launch, counts, t)
            self.map_t = t - t % self.period
        else:
            if self.plans.motion is not None:
                self.plans.motion.advance(t, self.plans.all_targets())
            if t - t % self.period != self.map_t:
                self.map_t = t - t % self.period
                self.plans.on_map(counts, self.map_t)
        if self.plans.motion is not None and gossip is not None and mask is not None and alive is not None:
            self.on_failures(t, mask, alive, gossip, nbr_t_rx, ego, nbr_state)
        own = self.plans.targets(np.arange(n))
        if self.last is not None:  # an agent its own copy counts as failed keeps its point
            own = np.where(np.isnan(own), self.last.double().numpy(), own)
        self.last = torch.from_numpy(own).to(ego.dtype)
        return self.last

    def on_failures(self, t: int, mask: torch.Tensor, alive: torch.Tensor, gossip: Gossip, t_rx: torch.Tensor,
                    ego: torch.Tensor, held: torch.Tensor) -> None:
        """Declare the neighbours out of N_i that are predicted in clear hearing and whose last
        message carried this agent's knowledge; then re-plan every copy whose agent's
        knowledge changed."""
        plans = self.plans
        assert plans is not None and plans.motion is not None
        n = mask.shape[-1]
        recent = self.instants.recent(t, self.declare_after + 1)
        missed = recent[: self.declare_after]  # the instants j must have missed, newest first
        silent = (t_rx >= 0) & (t_rx < missed[-1]) & ~torch.eye(n, dtype=torch.bool) & alive.unsqueeze(-1) & ~gossip.failed
        silent &= (t_rx == missed[0]).any(-1, keepdim=True)  # someone was heard at the newest instant
        silent &= may_predict(gossip.heard_rank, gossip.rank, self.instants.last(t))
        if len(missed) == self.declare_after and missed[-1] > 0 and bool(silent.any()):
            # Silent at the instants it missed, at each of which the plan-aware prediction
            # says it should have been heard (the tracker's beliefs, 30 s after the last
            # state, declared live teammates failed: docs/RESULTS.md, issue 24).
            sus = silent
            for at in missed:
                pred = plans.motion.at(at)[..., :3]
                own = pred[:, torch.arange(n), torch.arange(n)]  # (B, N, 3): each agent's own nominal then
                sus = suspects(sus, pred, torch.arange(n), own, self.channel, self.comm_m)
            if len(recent) > self.declare_after:  # or heard at the instant before, on a link the prediction keeps steady or clear enough
                st = hl = silent & (t_rx == recent[-1])
                before = plans.motion.at(recent[-1])[..., :3]
                for at in missed:
                    now = plans.motion.at(at)[..., :3]
                    st = steady(st, now, before, torch.arange(n), self.channel, self.comm_m)
                    hl = heard(hl, now, torch.arange(n), self.channel, self.comm_m)
                sus = sus | st | hl
            at = torch.full_like(gossip.epoch, self.instants.last(t))
            gossip.declare(sus, torch.where(sus.any(-1), at, torch.zeros_like(at)))
        known, since = gossip.failed.numpy(), gossip.since.numpy()
        live = alive.numpy()
        stale = live & ((known != plans.failed).any(-1) | (np.where(known, since, 0) != plans.since).any(-1))
        for e, a in zip(*np.nonzero(stale), strict=True):
            src = None
            if self.sources == "cv":  # p + v (epoch - t_rx) from the held states; itself: back from now
                def src(at: int, e: int = int(e), a: int = int(a)) -> np.ndarray:
                    xy = (held[e, a, :, :2] + held[e, a, :, 3:5] * (at - t_rx[e, a]).unsqueeze(-1)).double().numpy()
                    xy[a] = (ego[e, a, :2] + ego[e, a, 3:5] * (at - t)).double().numpy()
                    return xy
            if plans.settle(int(e), int(a), known[e, a].copy(), since[e, a].copy(), src):
                self.replans_done += 1
