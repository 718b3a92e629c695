"""One mission second of the agent: Algorithm 1 and the policy, and the command in force.

At each due second k (see `MissionClock.second_due`): book the misses of the instants
whose grace has passed (failure state f), advance Algorithm 1's tracker one second
(`predictor.pt`: beliefs and P-AoI from the held states; the steps of the seconds between
decisions run at the next decision, back to back, from copies of what was held then, as
nothing reads their beliefs sooner: `Decision.track`), and every tau seconds perceive
(`perceive`: ego at the first sample of second k, beliefs, N_i mask, sensing features, f,
demand map, and the agent's point of the team plan (`plan.AgentPlan`) for a policy that
takes it, moved toward its sensed users by the mission's `track_sensed_m`, as one
`PolicyInputs`) and run `policy.pt` on it through the typed call
(`learning/nn/contract.py::PolicyCall`) -> an acceleration, held until the next decision
(farther than the mission's `transit_plan_m` from the plan point, the plan follower's instead:
model/plan_follower.py).
The inputs are the twin's (`learning/nn/perception.py`, checked by the replay test): f
latches `model.signalling.silent_in_range` on the beliefs of the decision at which the twin
sees a drop (`failure.FailureFlag`; the twin uses `FailureFlags`) and the map is the newest
published one not after k (`demand.DemandMaps`). A policy of input version 1 gets what it
was trained with: no map, f = "a neighbour was dropped" (`NeighbourTable.lost`). `command()` is what goes to the
autopilot: before the mission a soft hold where offboard control began, then the
policy's acceleration through the altitude band guard.
"""

from __future__ import annotations

import collections
import logging
import math

import numpy as np
import torch

from plmarl_sitl.deploy.agent.clock import EPS, MissionClock
from plmarl_sitl.deploy.agent.coordination import agent_plan
from plmarl_sitl.deploy.agent.demand import DemandMaps
from plmarl_sitl.deploy.agent.failure import FailureFlag
from plmarl_sitl.deploy.agent.guard import band_guard
from plmarl_sitl.deploy.agent.inbox import SenseHistory
from plmarl_sitl.deploy.agent.neighbours import NeighbourTable
from plmarl_sitl.deploy.agent.plan import AgentPlan
from plmarl_sitl.deploy.agent.stats import LoopStats, Trace
from plmarl_sitl.deploy.mqtt.schema import Topics
from plmarl_sitl.learning.nn.contract import PolicyInputs
from plmarl_sitl.learning.nn.io import LoadedPolicy
from plmarl_sitl.mission import Mission
from plmarl_sitl.model.coverage import SENSING_FEATURES, sensing_features
from plmarl_sitl.model.plan_follower import PlanFollower
from plmarl_sitl.model.sensed_track import SlackCache, mission_toward_sensed

log = logging.getLogger("plmarl.agent")

HOLD_KP, HOLD_KD, HOLD_MAX_ACCEL = 0.3, 1.0, 2.5  # pre-mission hold: soft, so loop delays cannot make it ring


class Decision:
    def __init__(self, mission: Mission, me: int, lp: LoadedPolicy, clock: MissionClock, table: NeighbourTable,
                 stats: LoopStats, trace: Trace, topics: Topics, lockstep: bool = False,
                 airframe_drag_per_s: float = 0.0) -> None:
        self.mission, self.me, self.n = mission, me, mission.n_uavs
        # The airframe's linear drag per unit mass, 1/s, added back to the policy's command
        # (`command`): see AgentConfig.airframe_drag_per_s.
        self.drag_per_s = airframe_drag_per_s
        self.sense_topic = topics.sense(me)  # where sensing comes from (for the warning when it does not)
        self.tracker, self.policy = lp.tracker, lp.call  # policy(PolicyInputs) -> accel
        self.form = lp.form  # which inputs the file takes (and which f rule)
        self.flag = FailureFlag(self.n, clock.tau, float(lp.policy.r_comm))  # f of input version 2
        self.fail = False  # the f the policy got at the last decision
        self.demand = DemandMaps(mission, topics.demand)
        self.used_demand_t: float | None = None  # snapshot time of the map the last decision used
        # the plan's point: the team plan (model/service.py) or, with `coordination: local`, the neighbourhood plan
        self.plan = agent_plan(mission, me, table.knowledge) if self.form.takes_plan else None
        self.target: torch.Tensor | None = None  # that point at the last decision
        self.point: torch.Tensor | None = None  # the policy's target input then: the point moved toward the sensed users
        # In transit (mission `transit_plan_m`) a learnt policy's UAV flies the plan follower's command; a file
        # that is the plan follower already (policies/service, card `learnt: false`) flies its own everywhere.
        self.follower = PlanFollower(mission if lp.card.get("learnt", True) else mission.with_transit_plan(0.0))
        self.slack = SlackCache()  # the plan tree's slack, kept while the plan's points stay (model/sensed_track.py)
        self.new_map: torch.Tensor | None = None  # the map's cells when a decision of this second first used it (trace)
        self.vm = mission.vehicle_model()
        self.clock, self.table, self.stats, self.trace = clock, table, stats, trace
        # The latest telemetry's state, mission frame [p, v] float32: a numpy array per
        # sample (`observe`), its torch view (`ego`) made only when a second reads it. A
        # telemetry sample costs tens of microseconds of torch calls in a process that
        # slept since the last one (cold caches), ten times a second.
        self.ego_np = np.zeros(6, dtype=np.float32)
        self._ego: torch.Tensor | None = None
        self.hold_target: torch.Tensor | None = None  # pre-mission hold point (None: where the vehicle is)
        # Lockstep SITL: hold by damping only. The world places every vehicle at rest at the
        # twin's start state when it announces the start; a zero command then keeps it there
        # exactly, where a position hold would pull it back to where offboard control began.
        self.hold_damping_only = lockstep
        self.accel = (0.0, 0.0, 0.0)  # the command in force (before the band guard)
        self.ego_at: dict[int, np.ndarray | torch.Tensor] = {}  # the state at the first sample of each second not yet processed
        self.buf: torch.Tensor | None = None  # the tracker's state
        # The seconds processed since the last decision whose tracker step is still to run
        # (`track`): (second, held states, t_rx, its trace line without the P-AoI). Their
        # beliefs are read only at the next decision (and, free-running, at an instant's
        # delivery check), so their steps run there, back to back: a TorchScript call costs
        # a few times more alone, after the process slept, than right after another (issue 25.1).
        self.untracked: list[tuple[int, torch.Tensor, torch.Tensor, dict | None]] = []
        self.seen: torch.Tensor | None = None
        self.belief = torch.zeros(self.n, 6)
        self.aoi = torch.ones(self.n)
        # The last few sensing messages, (mission second, (K, 2) users in R_s): a decision at
        # k uses second k's users even when k+1's have already arrived (this agent ran late).
        self.sense_history: SenseHistory = collections.deque(maxlen=8)
        self.used_sense_t: float | None = None
        self.sense_warned = False

    @property
    def ego(self) -> torch.Tensor:
        """(6,) float32 the latest telemetry's state (a view of `ego_np`)."""
        if self._ego is None:
            self._ego = torch.from_numpy(self.ego_np)
        return self._ego

    @ego.setter
    def ego(self, state: torch.Tensor) -> None:
        self._ego, self.ego_np = state, state.numpy()

    def observe(self, state: np.ndarray) -> None:
        """The latest telemetry's state, (6,) float32 numpy (`VehicleSession.mission_state`)."""
        self.ego_np, self._ego = state, None

    @torch.inference_mode()
    def warm_up(self, calls: int = 4) -> None:
        """Run tracker and policy on this agent's shapes a few times before flying.

        TorchScript's profiling executor records and optimises a graph over the first
        calls; done mid-flight that costs milliseconds on the first decisions. The
        tracker's state here is scratch, not the agent's."""
        n = self.n
        held = torch.zeros(n, 6)
        held[:, 0] = torch.arange(n, dtype=torch.float32) * 40.0
        buf, seen = self.tracker.init_state(held)
        cells = self.demand.centres[: min(16, len(self.demand.centres))]
        demand = torch.cat([cells, torch.full((len(cells), 1), 5.0)], -1)
        for t in range(calls * 2):
            t_rx = torch.full((n,), float(t if t % 2 == 0 else t - 1))
            belief, _, buf, seen = self.tracker(float(t), held, t_rx, buf, seen)
            mask = torch.ones(n, dtype=torch.bool)
            mask[self.me] = False
            self.policy(PolicyInputs(held[self.me], belief, mask, torch.zeros(SENSING_FEATURES), torch.tensor(t % 4 == 3), demand))
        sensing_features(held[:1, :3], torch.zeros(3, 2), self.mission.radii.sensing_m, self.mission.users.cluster_size)

    def catch_up(self, tm: float) -> bool:
        """Mission time tm (the latest telemetry, `ego`): process every second now due;
        True if one of them decided."""
        clock = self.clock
        if tm < clock.next_k - EPS:
            return False  # within a second already processed: nothing is due (most samples)
        for k in range(clock.next_k, math.floor(tm + EPS) + 1):
            self.ego_at.setdefault(k, self.ego_np.copy())  # state at the first sample of second k
        decided = False
        while clock.second_due(clock.next_k, tm, self.awaiting_sensing(), self.delivered,
                               awaiting_demand=self.form.takes_demand and self.demand.awaiting(clock.next_k)):
            k = clock.next_k
            decided |= self.second(k, max(0.0, tm - k))
            clock.next_k = k + 1
        return decided

    def awaiting_sensing(self) -> bool:
        """No sensing message yet, and not yet given up on one."""
        return not self.sense_history and not self.sense_warned

    def delivered(self, k: int) -> bool:
        """Every neighbour expected to deliver for instant k has."""
        t_rx = self.table.t_rx
        return all(float(t_rx[j]) == k for j in self.expected(k))

    def expected(self, k: int) -> list[int]:
        """Neighbours whose update for instant k we wait for: at the first instant everyone;
        later those in N_i that the tracker believes within R_comm (one that has flown out
        of range will not deliver, and waiting for it would only delay the decision)."""
        others = [j for j in range(self.n) if j != self.me]
        if k == self.clock.first_k:
            return others
        self.track()  # the beliefs as of the last second processed
        r2 = self.mission.radii.comm_m ** 2
        d = self.belief[:, :3] - self.ego[:3]
        near = (d * d).sum(-1) <= r2
        return [j for j in others if self.table.in_set(j) and bool(near[j])]

    def _book_misses(self, k: int, sub_s: float) -> None:
        instants = self.clock.instants_to_book(k, sub_s)
        if instants:  # one second in T_up
            self._book(k, instants)

    @torch.inference_mode()
    def _book(self, k: int, instants: list[int]) -> None:
        for inst in instants:
            dropped = self.table.close_instant(float(inst))
            for j in dropped:
                log.warning("neighbour %d dropped at t = %d s (%d signalling instants missed)", j, k, self.table.drop)
            if dropped:
                self.flag.on_dropped(inst, dropped)

    def second(self, k: int, sub_s: float = 0.0) -> bool:
        """Mission second k (processed `sub_s` late): close the instant and, at a decision,
        advance the tracker to k (`track`) and decide; True if it decided."""
        self.stats.seconds += 1
        self._book_misses(k, sub_s)
        decided = self.clock.is_decision(k)
        ego = torch.as_tensor(self.ego_at.pop(k, self.ego_np))  # no copy: a numpy float32 array becomes its view
        for old in [s for s in self.ego_at if s < k]:
            del self.ego_at[old]
        mask = self.table.mask()
        self.new_map = None
        if not decided:  # the tracker's step waits for the next decision (`untracked`); the table changes in place: copies
            line = self._trace_line(k, ego, mask, decided) if self.trace.active else None
            self.untracked.append((k, self.table.state.clone(), self.table.t_rx.clone(), line))
            return False
        self.untracked.append((k, self.table.state, self.table.t_rx, None))
        self.track()
        inputs = self.perceive(k, ego, mask)
        a = self.follower.in_transit(self.policy(inputs), ego, self.target)  # the plan follower's in transit, as the twin
        if bool(inputs.fail) and not self.fail:
            log.warning("f = 1 at t = %d s (dropped: %s)", k, self.table.dropped)
        self.fail = bool(inputs.fail)
        ax, ay, az = a.tolist()  # one call, not three tensor indexings
        self.accel = (ax, ay, az)
        self.stats.decisions += 1
        if self.trace.active:
            line = self._trace_line(k, ego, mask, decided)
            line["aoi"] = self._aoi_line()
            self.trace.write(line)
        return True

    def track(self) -> None:
        """Run the tracker's steps of the seconds processed so far (`untracked`, oldest
        first) and write their trace lines: `belief` and `aoi` are then as of the last one."""
        for k, held, t_rx, line in self.untracked:
            if self.buf is None:
                self.buf, self.seen = self.tracker.init_state(held)
            self.belief, self.aoi, self.buf, self.seen = self.tracker(float(k), held, t_rx, self.buf, self.seen)
            if line is not None:
                line["aoi"] = self._aoi_line()
                self.trace.write(line)
        self.untracked.clear()

    def _aoi_line(self) -> list[float]:
        return [round(x, 2) for x in self.aoi.tolist()]  # tolist: iterating a tensor makes a tensor per element

    def _trace_line(self, k: int, ego: torch.Tensor, mask: torch.Tensor, decided: bool) -> dict:
        """Second k's trace line, as of now; its P-AoI ("aoi") is filled in after the tracker's step."""
        return {
            "t": k,
            "boot_s": round(self.clock.boot_s, 3),
            "aoi": None,
            "mask": mask.tolist(),
            "t_rx": [None if x < -1e8 else float(x) for x in self.table.t_rx.tolist()],
            "fail": self.table.lost,  # a neighbour was dropped
            "f": self.fail,  # the failure flag the policy got at the last decision
            "ego": [round(x, 2) for x in ego.tolist()],
            "accel": [round(x, 3) for x in self.accel],  # the policy's command
            "cmd": [round(x, 3) for x in self.command()],  # after the band guard
            "decided": decided,
            "sense_t": self.used_sense_t,  # the mission second of the users the last decision saw
            "demand_t": self.used_demand_t,  # the snapshot time of the map the last decision saw
            **({} if self.target is None else {"target": [round(x, 1) for x in self.target.tolist()]}),
            **({} if self.new_map is None else {"demand": self.new_map.tolist()}),  # that map's cells, when first used
        }

    def perceive(self, k: int, ego: torch.Tensor, mask: torch.Tensor) -> PolicyInputs:
        """The policy's inputs at decision k (the tracker has advanced to k): what the twin's
        `learning/nn/perception.py::Perception` gives its agents, from this agent's messages."""
        sense = self._sense(ego, k)
        if self.form.predicted_fail:
            fail = torch.tensor(self.flag.on_decision(k, self.belief, ego))
        else:  # input version 1: f = a neighbour was dropped
            fail = torch.tensor(self.table.lost)
        demand = target = None
        if self.form.takes_demand:
            got = self.demand.for_decision(k)
            if got is not None:
                if got[0] != self.used_demand_t:
                    self.new_map = got[1]
                demand = got[1]
            self.used_demand_t = None if got is None else got[0]
            if self.plan is not None:
                self.target = self.plan.target(k, ego, self.table.state, self.table.t_rx, got, mask,
                                               closed=self.table.closed)
                # moved toward the sensed users (mission `track_sensed_m`, model/sensed_track.py), as the twin's Perception
                self.point = target = mission_toward_sensed(self.mission, self.target, ego, sense, self._team, self.slack)
        return PolicyInputs(ego, self.belief, mask, sense, fail, demand, target)

    def _team(self) -> tuple[torch.Tensor | None, torch.Tensor | None]:
        """This agent's copy of the team plan's points and its identity (model/sensed_track.py);
        (None, None) with the neighbourhood plan or before the plan starts."""
        points = self.plan.team_points() if isinstance(self.plan, AgentPlan) else None
        return (None, None) if points is None else (points, torch.tensor(self.me))

    def _sense(self, ego: torch.Tensor, k: int) -> torch.Tensor:
        """Sensing features of the newest users' message not after second k (usually
        second k - 1: the world publishes second k's a moment after its telemetry)."""
        m = self.mission
        if not self.sense_history:
            if not self.sense_warned:
                self.sense_warned = True
                log.warning("no sensing publisher on %s: flying as if no users are sensed", self.sense_topic)
            return torch.zeros(SENSING_FEATURES)
        t, users = next(((t, u) for t, u in reversed(self.sense_history) if t <= k + 1e-6), self.sense_history[0])
        self.used_sense_t = t
        users = torch.as_tensor(users, dtype=torch.float32).reshape(-1, 2)  # as received (inbox.SenseHistory)
        return sensing_features(ego[:3].unsqueeze(0), users, m.radii.sensing_m, m.users.cluster_size)[0]

    def command(self) -> tuple[float, float, float]:
        """The acceleration to send now (NED, m/s^2)."""
        vm = self.vm
        ego = self.ego_np.tolist()  # once per sample: Python floats (the float32 values), no torch
        alt, v_up = -ego[2], -ego[5]
        if not self.clock.in_mission():
            # Before the mission: hold where offboard control began (PD on position).
            tgt = self.hold_target if self.hold_target is not None and not self.hold_damping_only else self.ego[:3]
            a = HOLD_KP * (tgt - self.ego[:3]) - HOLD_KD * self.ego[3:]
            norm = float(torch.linalg.vector_norm(a))
            if norm > HOLD_MAX_ACCEL:
                a = a * (HOLD_MAX_ACCEL / norm)
            return float(a[0]), float(a[1]), float(a[2])
        a = band_guard(self.accel, alt, v_up, vm.min_alt_m, vm.max_alt_m, vm.max_accel_mps2)
        if self.drag_per_s:
            # The policy means a net acceleration of the mission's drag-free point mass. An
            # autopilot that flies acceleration setpoints open loop (PX4's feed-forward) gets
            # -k v of it eaten by the airframe's drag: ask for a + k v so the net is a.
            # Horizontally only: PX4 sets the vertical thrust from its hover-thrust estimate,
            # whose error is a constant vertical acceleration (SIH under afz 0: +1.2 m/s up,
            # docs/CONFORMANCE.md); the drag is what bounds it, and cancelling the drag
            # integrated it into +-8 m/s swings over 70-170 m (measured on real PX4).
            k = self.drag_per_s
            a = (a[0] + k * ego[3], a[1] + k * ego[4], a[2])
        return a
