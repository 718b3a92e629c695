"""The agent's bus input: payloads decoded into the neighbour table, the clock, the
sensing history and the demand maps; anything malformed is counted by reason (`rx`, in
the agent's stats: `malformed_<reason>`, `malformed_demand_<reason>`, ...) and changes nothing."""

from __future__ import annotations

import logging
from collections import deque

import torch

from plmarl_sitl.deploy.agent.clock import MissionClock
from plmarl_sitl.deploy.agent.demand import DemandMaps
from plmarl_sitl.deploy.agent.neighbours import NeighbourTable
from plmarl_sitl.deploy.mqtt.demand import decode_demand
from plmarl_sitl.deploy.mqtt.schema import (
    Malformed,
    RxCounters,
    SeqFilter,
    Topics,
    decode_json,
    decode_sense,
    decode_state,
    split_states,
)

log = logging.getLogger("plmarl.agent")

# (mission second, (K, 2) positions of the users in sensing range)
SenseHistory = deque[tuple[float, torch.Tensor]]


def subscriptions(topics: Topics, me: int, bus_mode: str) -> list[str]:
    """What agent `me` listens to: its sensing, the demand map, the mission start and
    control, and its neighbours' states (relayed by the SITL world, or straight from tx/+
    with `direct`)."""
    subs = [topics.sense(me), topics.demand, topics.start, topics.ctl]
    return subs + ([topics.tx("+")] if bus_mode == "direct" else [topics.rx(me), topics.closed])


class Inbox:
    def __init__(self, topics: Topics, me: int, n: int, table: NeighbourTable, clock: MissionClock,
                 sense_history: SenseHistory, demand: DemandMaps, *, wait_start: bool) -> None:
        self.topics, self.me, self.n = topics, me, n
        self.table, self.clock, self.sense_history, self.demand = table, clock, sense_history, demand
        self.wait_start = wait_start  # take t0 from the world's start announcement
        self.rx = RxCounters()
        self.seq_filter = SeqFilter()

    def on_message(self, topic: str, payload: bytes) -> None:
        """One bus message (the bus's callback: must not block)."""
        t = self.topics
        if topic == t.sense(self.me):
            self._on_sense(payload)
        elif topic == t.demand:
            self._on_demand(payload)
        elif topic == t.start:
            self._on_start(payload)
        elif topic == t.closed:
            try:
                self.clock.on_closed(float(decode_json(payload)["t_s"]))
            except (Malformed, KeyError, TypeError, ValueError):
                self.rx.bad("closed")
        elif topic == t.ctl:
            self._on_ctl(payload)
        else:
            self._on_states(payload)

    def _on_sense(self, payload: bytes) -> None:
        try:
            msg = decode_sense(payload)
        except Malformed as exc:
            self.rx.bad(f"sense_{exc.reason}")
            return
        self.sense_history.append((msg.t_ms / 1000.0, torch.tensor(msg.users, dtype=torch.float32).reshape(-1, 2)))

    def _on_demand(self, payload: bytes) -> None:
        if not payload:
            return  # the world clears a previous run's retained map with an empty payload
        try:
            msg = decode_demand(payload)
        except Malformed as exc:
            self.rx.bad(f"demand_{exc.reason}")
            return
        self.demand.on_message(msg)

    def _on_start(self, payload: bytes) -> None:
        if not payload:
            return  # the world clears a previous run's retained start with an empty payload
        try:
            obj = decode_json(payload)
            t0 = float(obj["t0_boot_s"])
            # Vehicles with clocks of their own (real autopilots, each booted when its agent
            # connected) get t0 each on their own clock; emulated ones share the host's.
            by_uav = obj.get("t0_boot_s_by_uav")
            if by_uav is not None:
                t0 = float(by_uav[self.me])
        except (Malformed, KeyError, IndexError, TypeError, ValueError):
            self.rx.bad("start")
            return
        n = obj.get("n_uavs", self.n)
        if n != self.n:
            log.error("the world has %s UAVs, this agent was started for %d (--n-uavs)", n, self.n)
        if self.clock.t0 is None and self.wait_start:
            self.clock.set_t0(t0)

    def _on_ctl(self, payload: bytes) -> None:
        if not payload:
            return
        try:
            tup = int(decode_json(payload)["tup_s"])
        except (Malformed, KeyError, TypeError, ValueError):
            self.rx.bad("ctl")
            return
        if tup >= 1 and tup != self.clock.tup:
            log.info("T_up changed %d -> %d s", self.clock.tup, tup)
            self.clock.set_tup(tup)

    def _on_states(self, payload: bytes) -> None:
        """A batch of state messages (one or more, back to back): a batch that is not
        whole messages is dropped whole; a bad message in a good batch only itself."""
        try:
            parts = split_states(payload)
        except Malformed as exc:
            self.rx.bad(exc.reason)
            return
        for part in parts:
            self._on_state(part)

    def _on_state(self, payload: bytes) -> None:
        try:
            msg = decode_state(payload)
        except Malformed as exc:
            self.rx.bad(exc.reason)
            return
        if msg.sender == self.me:
            self.rx.self_echo += 1
            return
        if not 0 <= msg.sender < self.n:
            self.rx.unknown_sender += 1
            return
        why = self.seq_filter.check(msg)
        if why == "duplicate":
            self.rx.duplicate += 1
        elif why == "out_of_order":
            self.rx.out_of_order += 1
        elif self.table.on_state(msg.sender, msg.t_s, msg.state):
            self.rx.accepted += 1
        else:
            self.rx.out_of_order += 1
