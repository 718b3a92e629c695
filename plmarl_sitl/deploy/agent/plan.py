"""This agent's copy of the team plan (model/service.py): its own point, from the launch
line it heard at its first decision and the demand maps it received.

The twin's controllers run the same `TeamPlans` (learning/nn/plan.py::ServiceTargets) on
the same information, so the agent's target equals its twin's: the plan starts at the first
decision that has a map, from the states received at the first decision (the launch line;
the decision at the first instant waits for every neighbour), and follows each new map
when a decision first uses it.

The first instant's wait is bounded, and on a busy bus its states can arrive a second or
two after it (late states count as delivered, docs/SIGNALLING.md). A launch line fitted
without them gives several agents the same point for the whole mission (seen in SITL at
load 20: three of four UAVs on one cluster), so states of the first instant that arrive
later, while the plan still follows its first map, are added and the plan restarted from
that map: the plan the twin, which hears them at once, started with.

Failures (issue 24, model/gossip.py) as the twin's `ServiceTargets.on_failures`: at each
decision, a neighbour silent at the `DECLARE_AFTER_MISSED` newest instants whose misses
are booked (the table's `closed`; in lockstep the newest instant, as in the twin), that the
plan-aware prediction put in clear hearing at each (or, heard at the instant before, on a
steady link or one predicted clear enough), and whose last
message knew this agent's declarations before then, is declared failed at the newest
signalling instant; the knowledge the table merged from received states and these
declarations (with the refutations of identities heard again, model/knowledge.py), as of
the decision, is what the plan settles to (`TeamPlans.settle`) whenever it changes.
The state message of instant k carries `NeighbourTable.knowledge.view(before=k)` (core.py).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch

from plmarl_sitl.learning.nn.plan import SignallingInstants, heard_launch, motion_of, repairer_of, service_grid
from plmarl_sitl.mission import Mission
from plmarl_sitl.model.gossip import DECLARE_AFTER_MISSED, NOTHING, Knowledge, clear_hearing, heard_links, steady_links
from plmarl_sitl.model.service import TeamPlans, grid_counts, mission_launch_xy


class LinkTables:
    """The failure check's link tables (model/gossip.py: which links the predicted positions
    give a clear or steady hearing), kept per signalling instant while the predictions they
    were computed from are unchanged. They depend on the predicted positions alone, which
    change only at a new instant or a re-plan, while the check runs at every decision
    (tau = 3 s, T_up 15 s: five times an instant) whenever a neighbour is silent; the
    U2U SINR over the team was ~6 % of an agent's busy time at N = 20 (issue 25)."""

    KEEP = 8  # tables: a few instants' worth

    def __init__(self) -> None:
        self.tables: dict[tuple, tuple[tuple[np.ndarray, ...], np.ndarray]] = {}

    def get(self, key: tuple, inputs: tuple[np.ndarray, ...], compute: Callable[[], np.ndarray]) -> np.ndarray:
        """The table under key, computed anew unless it was computed from inputs equal to these."""
        held = self.tables.get(key)
        if held is not None and all(np.array_equal(a, b) for a, b in zip(held[0], inputs, strict=True)):
            return held[1]
        table = compute()
        self.tables.pop(key, None)
        self.tables[key] = (tuple(x.copy() for x in inputs), table)
        while len(self.tables) > self.KEEP:
            del self.tables[next(iter(self.tables))]
        return table


class AgentPlan:
    def __init__(self, mission: Mission, me: int, knowledge: Knowledge | None = None) -> None:
        self.me, self.n = me, mission.n_uavs
        self.grid = service_grid(mission)
        self.instants = SignallingInstants(mission)
        self.channel, self.comm_m = mission.channel, float(mission.radii.comm_m)
        self.declare_after = DECLARE_AFTER_MISSED
        self.knowledge = knowledge if knowledge is not None else Knowledge(me)  # the neighbour table's
        self.plans = TeamPlans(self.grid, self.n, motion_of(mission, self.instants), repairer_of(mission))
        self.nominal = mission_launch_xy(mission)  # the mission's launch line (model/service.py::launch_line)
        self.launch: np.ndarray | None = None  # (n, 2) the launch line fitted through the heard states
        self.first_k: int | None = None  # the first decision's second (its signalling instant)
        self.heard_xy: dict[int, np.ndarray] = {}  # identity -> position in its state of that instant (me included)
        self.map_t: float | None = None  # snapshot time of the map the plan follows
        self.first_counts: np.ndarray | None = None  # the first map, while the plan still follows it
        self.started = False
        self.point: torch.Tensor | None = None  # this agent's point, recomputed only when the plan changes
        self.links = LinkTables()  # the failure check's link tables, per signalling instant
        self.me_t = torch.tensor([self.me])  # this agent's identity, as the link functions take it
        self.goals: np.ndarray | None = None  # (1, 1, n, 2) every identity's point: the plan's, kept until it changes

    def team_points(self) -> torch.Tensor | None:
        """(n, 2) float64 every identity's point in this agent's copy (NaN: failed); None before the
        plan starts. What bounds the sensed-users shift (model/sensed_track.py), as the twin's `copy_points`."""
        return None if self.plans.points is None else torch.from_numpy(self.plans.all_targets()[0, 0])

    def target(self, k: int, ego: torch.Tensor, held: torch.Tensor, t_rx: torch.Tensor,
               demand: tuple[float, torch.Tensor] | None, mask: torch.Tensor | None = None,
               closed: int | None = None) -> torch.Tensor | None:
        """At a decision at second k: (2,) float32 north, east of this agent's point, or None
        before a map has arrived. held (n, 6) / t_rx (n,): the neighbour table; mask (n,) its
        N_i, for failures (without: no failure re-plans); closed: the newest signalling
        instant whose misses the table has booked (None: the newest instant, as the twin)."""
        if self.first_k is None:
            self.first_k = k
            self.heard_xy[self.me] = ego[:2].double().numpy()
        late = self.hear_first_instant(held, t_rx)
        if demand is None:
            return None
        t_map, cells = demand
        # The map onto the plan grid only when the plan takes a new map (~120 us at N = 20):
        # a decision on the map the plan follows needs only the lookup below.
        new_map = not self.started or t_map != self.map_t
        counts = grid_counts(cells.double().numpy(), self.grid)[None] if new_map else None
        changed = True
        if not self.started:
            self.plans.start(self.launch[None, None], counts, k)
            self.started, self.first_counts = True, counts
        else:
            self.plans.motion.advance(k, self.goals)  # the points held since the last decision
            if new_map:
                self.plans.on_map(counts, round(t_map))
                self.first_counts = None  # the plan has moved on: too late to restart it
            elif late and self.first_counts is not None:
                self.plans.start(self.launch[None, None], self.first_counts, self.first_k)
                self.plans.motion.advance(k, self.plans.all_targets())
            else:
                changed = False
        self.map_t = t_map
        if mask is not None:
            changed |= self.on_failures(k, t_rx, self.instants.last(k) if closed is None else min(closed, k))
        if changed:
            self.goals = self.plans.all_targets()
            own = self.plans.targets(np.array([self.me]))[0, 0]
            if not np.isnan(own).any():  # a copy that counts this agent as failed: it keeps its point
                self.point = torch.from_numpy(own).to(torch.float32)
        return self.point

    def on_failures(self, k: int, t_rx: torch.Tensor, closed: int) -> bool:
        """Declare the neighbours silent at the `DECLARE_AFTER_MISSED` newest booked instants
        (up to `closed`), predicted in clear hearing at each, whose last message carried this
        agent's knowledge (model/gossip.py); re-plan if what this agent knows changed. True if
        the plan changed."""
        known = self.knowledge.view(before=k + 1)
        newest = self.instants.last(k)

        def may_predict(j: int) -> bool:  # model.gossip.may_predict, on Known values
            return known.predicts_alike(self.knowledge.heard.get(j, NOTHING), newest)

        recent = self.instants.recent(closed, self.declare_after + 1)
        missed = recent[: self.declare_after]  # newest first
        # The table's slots as numpy vectors: per-slot Python over N teammates cost ~50 us a decision at N = 100
        rx = t_rx.numpy()
        others = np.arange(self.n) != self.me
        heard = bool((others & (rx >= missed[0])).any())  # someone at the newest instant
        silent = [j for j in np.flatnonzero(others & (rx >= 0) & (rx < missed[-1])).tolist()
                  if j not in known.failed and may_predict(j)] \
            if heard and len(missed) == self.declare_after and missed[-1] > 0 else []
        if silent:
            # (n,) numpy bool vectors throughout (the link tables are kept as numpy rows of
            # this agent's copy): a handful of torch calls on 20 booleans cost more than the
            # check's arithmetic in a process whose caches went cold since the last second.
            silent_v = np.zeros(self.n, dtype=bool)
            silent_v[silent] = True
            sus = silent_v
            me = self.me_t
            for at in missed:  # model.gossip.suspects, its link table kept while the prediction is
                pred = self.plans.motion.at_array(at)[..., :3]
                sus = sus & self.links.get(("clear", at), (pred,), lambda p=pred: clear_hearing(
                    torch.from_numpy(p), me, torch.from_numpy(p)[:, :, self.me], self.channel, self.comm_m)[0, 0].numpy())
            if len(recent) > self.declare_after:  # or heard at the instant before, on a steady link or one
                # predicted clear enough (model/gossip.py::steady, ::heard)
                st = hl = silent_v & (rx == recent[-1])
                before = self.plans.motion.at_array(recent[-1])[..., :3]
                for at in missed:
                    now = self.plans.motion.at_array(at)[..., :3]
                    st = st & self.links.get(("steady", at, recent[-1]), (now, before), lambda n=now: steady_links(
                        torch.from_numpy(n), torch.from_numpy(before), me, self.channel, self.comm_m)[0, 0].numpy())
                    hl = hl & self.links.get(("heard", at), (now,), lambda n=now: heard_links(
                        torch.from_numpy(n), me, self.channel, self.comm_m)[0, 0].numpy())
                sus = sus | st | hl
            ids = np.flatnonzero(sus)
            if len(ids):
                self.knowledge.learn(k, known.declared([int(j) for j in ids], self.instants.last(k)))
                known = self.knowledge.view(before=k + 1)
        failed = np.zeros(self.n, dtype=bool)
        since = np.zeros(self.n, dtype=np.int64)
        for j, s in known.failed.items():
            failed[j], since[j] = True, s
        return self.plans.settle(0, 0, failed, since)

    def hear_first_instant(self, held: torch.Tensor, t_rx: torch.Tensor) -> bool:
        """Add the neighbours whose state of the first instant is now held and refit the launch
        line; True if a state arrived after the first decision (the line changed)."""
        # One vector comparison: a per-slot float() of the table costs ~2 us a neighbour, every decision.
        new = [j for j in np.flatnonzero(t_rx.numpy() == float(self.first_k)).tolist() if j not in self.heard_xy]
        for j in new:
            self.heard_xy[j] = held[j, :2].double().numpy()
        if self.launch is not None and not new:
            return False
        heard = np.array([j in self.heard_xy and j != self.me for j in range(self.n)])
        xy = np.stack([self.heard_xy.get(j, np.zeros(2)) for j in range(self.n)])
        late = self.launch is not None
        self.launch = heard_launch(self.heard_xy[self.me], xy, heard, self.me, self.nominal)
        return late

