"""The agent's bus input: payloads decoded into the neighbour table, the clock, the
sensing history and the demand maps; anything malformed is counted by reason (`rx`, in
the agent's stats: `malformed_<reason>`, `malformed_demand_<reason>`, ...) and changes nothing.

With a signed wire (`wire.Wire` with the swarm key) every message must authenticate
first; one that does not (unsigned, wrong key, forged), a state outside the freshness
window, a state or sensing message whose id disagrees with its topic, and a `ctl` whose
counter does not advance are counted (`unsigned`, `wrong_key`, `forged`, `out_of_window`,
`misattributed`, `out_of_order`, and per message class in `auth_<class>_<reason>`) and
dropped: the agent keeps flying on its predictions."""

from __future__ import annotations

import logging
from collections import deque
from collections.abc import Callable

import torch

from plmarl_sitl.deploy.agent.clock import MissionClock
from plmarl_sitl.deploy.agent.demand import DemandMaps
from plmarl_sitl.deploy.agent.neighbours import NeighbourTable
from plmarl_sitl.deploy.mqtt.auth import AuthError
from plmarl_sitl.deploy.mqtt.schema import WINDOW_SLACK_S, Malformed, RxCounters, SeqFilter, Topics
from plmarl_sitl.deploy.mqtt.wire import Wire

log = logging.getLogger("plmarl.agent")

# (mission second, the users in sensing range: K (north, east) pairs as received, or a
# (K, 2) tensor). Kept as received: a decision (one second in tau) reads one of them
# (`Decision._sense` makes the tensor), the other messages are never read.
SenseHistory = deque[tuple[float, "torch.Tensor | tuple[tuple[float, float], ...]"]]


def subscriptions(topics: Topics, me: int, bus_mode: str, lockstep: bool = False) -> list[str]:
    """What agent `me` listens to: its sensing, the demand map, the mission start and
    control, and its neighbours' states (relayed by the SITL world, or straight from tx/+
    with `direct`); in lockstep SITL also the world's ticks."""
    subs = [topics.sense(me), topics.demand, topics.start, topics.ctl]
    if bus_mode == "direct":
        return [*subs, topics.tx("+")]
    return [*subs, topics.rx(me), topics.closed, *([topics.tick] if lockstep else [])]


class Inbox:
    def __init__(self, topics: Topics, me: int, n: int, table: NeighbourTable, clock: MissionClock,
                 sense_history: SenseHistory, demand: DemandMaps, *, wait_start: bool, wire: Wire | None = None,
                 on_tick: Callable[[float], None] | None = None) -> None:
        self.topics, self.me, self.n = topics, me, n
        self.table, self.clock, self.sense_history, self.demand = table, clock, sense_history, demand
        self.wait_start = wait_start  # take t0 from the world's start announcement
        self.wire = wire or Wire(None)
        self.rx = RxCounters()
        self.seq_filter = SeqFilter()
        self.ctl_seq = -1  # signed wire: the counter of the last ctl applied
        self.on_tick = on_tick  # a lockstep world's tick (boot second) goes here

    def on_message(self, topic: str, payload: bytes) -> None:
        """One bus message (the bus's callback: must not block)."""
        t = self.topics
        try:
            if topic == t.sense(self.me):
                self._on_sense(payload)
            elif topic == t.demand:
                self._on_demand(payload)
            elif topic == t.start:
                self._on_start(payload)
            elif topic == t.closed:
                self._on_closed(payload)
            elif topic == t.tick:
                self._on_tick(payload)
            elif topic == t.ctl:
                self._on_ctl(payload)
            else:
                self._on_states(topic, payload)
        except AuthError as exc:  # states are counted one by one in _on_states
            self.rx.refused(exc.reason, "sense" if topic == t.sense(self.me) else topic.rsplit("/", 1)[-1])

    def _on_closed(self, payload: bytes) -> None:
        try:
            self.clock.on_closed(float(self.wire.read_json("closed", payload)["t_s"]))
        except (Malformed, KeyError, TypeError, ValueError):
            self.rx.bad("closed")

    def _on_tick(self, payload: bytes) -> None:
        if not payload or self.on_tick is None:
            return  # the world clears a previous run's retained tick with an empty payload
        try:
            boot_s = float(self.wire.read_json("tick", payload)["boot_s"])
        except (Malformed, KeyError, TypeError, ValueError):
            self.rx.bad("tick")
            return
        self.on_tick(boot_s)

    def _on_sense(self, payload: bytes) -> None:
        try:
            msg = self.wire.read_sense(payload)
        except Malformed as exc:
            self.rx.bad(f"sense_{exc.reason}")
            return
        if msg.receiver != self.me:
            self.rx.refused("misattributed", "sense")
            return
        self.sense_history.append((msg.t_ms / 1000.0, msg.users))

    def _on_demand(self, payload: bytes) -> None:
        if not payload:
            return  # the world clears a previous run's retained map with an empty payload
        try:
            msg = self.wire.read_demand(payload)
        except Malformed as exc:
            self.rx.bad(f"demand_{exc.reason}")
            return
        self.demand.on_message(msg)

    def _on_start(self, payload: bytes) -> None:
        if not payload:
            return  # the world clears a previous run's retained start with an empty payload
        try:
            obj = self.wire.read_json("start", payload)
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
            obj = self.wire.read_json("ctl", payload)
            tup = int(obj["tup_s"])
            seq = int(obj["seq"]) if self.wire.signed else 0
        except (Malformed, KeyError, TypeError, ValueError):
            self.rx.bad("ctl")
            return
        if self.wire.signed:
            if seq <= self.ctl_seq:  # a replayed older order
                self.rx.out_of_order += 1
                return
            self.ctl_seq = seq
        if tup >= 1 and tup != self.clock.tup:
            log.info("T_up changed %d -> %d s", self.clock.tup, tup)
            self.clock.set_tup(tup)

    def _on_states(self, topic: str, payload: bytes) -> None:
        """A batch of state messages (one or more, back to back): a batch that is not
        whole messages is dropped whole; a bad message in a good batch only itself.
        On tx/<j> (direct bus) every message must be j's own."""
        try:
            parts = self.wire.split_states(payload)
        except Malformed as exc:
            self.rx.bad(exc.reason)
            return
        from_topic = self.topics.id_of(topic) if topic != self.topics.rx(self.me) else None
        for part in parts:
            try:
                self._on_state(part, from_topic)
            except AuthError as exc:
                self.rx.refused(exc.reason, "state")

    def _fresh(self, t_s: float) -> bool:
        """A signed state's instant is within the window of our clock (unknown clock: yes)."""
        now = self.clock.mission_now()
        return not self.wire.signed or now is None or now - self.clock.tup - WINDOW_SLACK_S <= t_s <= now + WINDOW_SLACK_S

    def _on_state(self, payload: bytes, from_topic: int | None) -> None:
        try:
            msg = self.wire.read_state(payload)
        except Malformed as exc:
            self.rx.bad(exc.reason)
            return
        if from_topic is not None and msg.sender != from_topic:
            self.rx.refused("misattributed", "state")
            return
        if not self._fresh(msg.t_s):
            self.rx.refused("out_of_window", "state")
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
        elif self.table.on_state(msg.sender, msg.t_s, msg.state, msg.known()):
            self.rx.accepted += 1
        else:
            self.rx.out_of_order += 1
