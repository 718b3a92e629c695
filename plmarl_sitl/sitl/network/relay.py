"""The SITL world's signal relay: each state on `tx/<j>` to every UAV that hears j now.

Who hears a sender is the link emulator's answer (`network.link_emulator`: R_comm and
SINR >= Gamma, cuts, loss), decided when the state arrives; the deliveries go out after an
optional latency in sim time. A state is relayed once, and only if it authenticates
(signed wire), names its own sender, lies in the mission clock's window and is not a replay.

States are gathered by signalling instant. An instant closes when every live vehicle has
signalled (or, `close_overdue`, half the agents' wait bound later): its deliveries go out
as one rx message per receiver (N messages per instant instead of N (N - 1) through the
broker), then a `closed` marker, so no agent waits out its timeout for a neighbour that is
out of range (real radios have no marker: agents wait the timeout). A state late for its
closed instant goes out on its own.

Lockstep (`lockstep_wake` given) holds each instant's states by sender instead, and the
lockstep pacer has them relayed, in sender order (the loss draws too), when the instant
closes (`relay_instant`): the same outputs under any machine load.
"""

from __future__ import annotations

import heapq
import itertools
import math
from collections.abc import Callable

from plmarl_sitl.deploy.mqtt.auth import AuthError
from plmarl_sitl.deploy.mqtt.schema import (
    INSTANT_WAIT_MIN_S,
    INSTANT_WAIT_WALL_S,
    WINDOW_SLACK_S,
    Malformed,
    SeqFilter,
    Topics,
)
from plmarl_sitl.deploy.mqtt.wire import Wire
from plmarl_sitl.sitl.network.link_emulator import LinkEmulator
from plmarl_sitl.sitl.outbox import Outbox
from plmarl_sitl.sitl.start import MissionTime
from plmarl_sitl.sitl.vehicles import WorldVehicles


class Relay:
    def __init__(self, links: LinkEmulator, vehicles: WorldVehicles, outbox: Outbox, wire: Wire, topics: Topics,
                 time: MissionTime, latency_s: float = 0.0, speedup: float = 1.0,
                 lockstep_wake: Callable[[], None] | None = None) -> None:
        self.links, self.vehicles, self.outbox, self.wire, self.topics = links, vehicles, outbox, wire, topics
        self.time = time
        self.n = vehicles.n
        self.latency_s = latency_s  # sim seconds between a tx and its deliveries
        self.speedup = speedup  # the agents' wait bound is wall time: x speedup in vehicle time
        self.lockstep_wake = lockstep_wake  # lockstep: wakes the barrier when a state is held
        self.seq_filter = SeqFilter()  # relays each state once: a replay is not relayed again
        self.on_signal: Callable[[str, bytes], None] | None = None  # each tx relayed and rx sent, in order
        self._pending: list[tuple[float, int, str, bytes]] = []  # (due sim s, tiebreak, topic, payload)
        self._tiebreak = itertools.count()
        self._instants: dict[float, set[int]] = {}  # open signalling instants: who has signalled
        self._batches: dict[float, dict[int, list[bytes]]] = {}  # deliveries of each open instant, per receiver
        self._closed_upto = -math.inf  # instants up to here are closed: late updates go out alone
        self._held: dict[float, dict[int, bytes]] = {}  # lockstep: each open instant's states by sender

    # ------------------------------------------------------------------ arrival
    def on_message(self, topic: str, payload: bytes) -> None:
        """A state on tx/<sender>: checked, then gathered into its instant (or held, or late)."""
        sender = self.topics.id_of(topic)
        counters = self.links.counters
        try:
            msg = self.wire.read_state(payload)
        except Malformed:
            counters.malformed += 1
            return
        except AuthError as exc:
            setattr(counters, exc.reason, getattr(counters, exc.reason) + 1)
            return
        if sender is None or not 0 <= sender < self.n:
            counters.malformed += 1
            return
        if msg.sender != sender:
            counters.misattributed += 1
            return
        if self.wire.signed and self.time.t0 is not None:
            now_t = self.vehicles.now - self.time.t0
            if not now_t - self.time.tup_s - WINDOW_SLACK_S <= msg.t_s <= now_t + WINDOW_SLACK_S:
                counters.out_of_window += 1
                return
        if self.seq_filter.check(msg) is not None:
            counters.replayed += 1
            return
        if self.lockstep_wake is not None and msg.t_s > self._closed_upto:
            self._held.setdefault(msg.t_s, {})[sender] = payload
            self.lockstep_wake()
            return
        pos = self.vehicles.positions()
        alive = self.vehicles.alive()
        receivers = self.links.receivers(sender, pos, alive, self.vehicles.now)  # decided at arrival
        if msg.t_s <= self._closed_upto:  # late for its instant: deliver it on its own
            for i in receivers:
                self._send_after_latency(self.topics.rx(i), payload)
            return
        batch = self._batches.setdefault(msg.t_s, {})
        for i in receivers:
            batch.setdefault(i, []).append(payload)
        heard = self._instants.setdefault(msg.t_s, set())
        heard.add(sender)
        if heard >= {i for i in range(self.n) if bool(alive[i])}:
            self._close_instant(msg.t_s)

    # ------------------------------------------------------------------ lockstep
    def holds(self, k: float) -> bool:
        """Lockstep: some state of instant k is held."""
        return k in self._held

    def held_senders(self, k: float) -> set[int]:
        """Lockstep: who has signalled instant k."""
        return set(self._held.get(k, {}))

    def relay_instant(self, k: float) -> None:
        """Lockstep: relay instant k's held states in sender order, then close it (one rx per
        receiver, closed). An emulated broker outage swallows them."""
        held = self._held.pop(k, {})
        if self.outbox.outage_at(int(k)):
            self.links.counters.outage += len(held)
            held = {}
        pos, alive = self.vehicles.positions(), self.vehicles.alive()
        batch = self._batches.setdefault(k, {})
        for sender in sorted(held):
            if self.on_signal is not None:
                self.on_signal(self.topics.tx(sender), held[sender])
            for i in self.links.receivers(sender, pos, alive, self.vehicles.now):
                batch.setdefault(i, []).append(held[sender])
        self._close_instant(k)

    # ------------------------------------------------------------------ between chunks of time
    @property
    def idle(self) -> bool:
        """Nothing falls due as vehicle time moves (no delayed delivery, no open instant):
        `pump` would do nothing until a new state arrives."""
        return not self._pending and not self._instants

    def pump(self) -> None:
        """What falls due as vehicle time moves: overdue instants close, delayed deliveries go out."""
        self.close_overdue()
        self.deliver_due()

    def close_overdue(self) -> None:
        """Close every open instant some updates are still missing from after half the
        agents' own wait bound (a vehicle whose agent died signals no more): the others'
        updates must reach them before they give up waiting."""
        if not self._instants or self.time.t0 is None:
            return
        now_t = self.vehicles.now - self.time.t0
        wait = max(INSTANT_WAIT_MIN_S, 0.5 * INSTANT_WAIT_WALL_S * self.speedup)
        for t_s in [t for t in self._instants if now_t >= t + wait]:
            self._close_instant(t_s)

    def deliver_due(self) -> None:
        while self._pending and self._pending[0][0] <= self.vehicles.now:
            _, _, topic, payload = heapq.heappop(self._pending)
            if self.outbox.cut:  # lockstep: an emulated outage swallows deliveries still under way
                self.links.counters.outage += 1
                continue
            self._publish(topic, payload)

    # ------------------------------------------------------------------ out
    def _close_instant(self, t_s: float) -> None:
        """Deliver instant t_s's updates, one rx message per receiver, then the marker that
        it has delivered all it will (through the same latency queue)."""
        self._instants.pop(t_s, None)
        self._closed_upto = max(self._closed_upto, t_s)
        for i, payloads in sorted(self._batches.pop(t_s, {}).items()):
            self._send_after_latency(self.topics.rx(i), b"".join(payloads))
        self._send_after_latency(self.topics.closed, self.wire.json("closed", {"t_s": t_s}))

    def _send_after_latency(self, topic: str, payload: bytes) -> None:
        if self.latency_s > 0:
            heapq.heappush(self._pending, (self.vehicles.now + self.latency_s, next(self._tiebreak), topic, payload))
        else:
            self._publish(topic, payload)

    def _publish(self, topic: str, payload: bytes) -> None:
        if self.on_signal is not None:
            self.on_signal(topic, payload)
        self.outbox.publish(topic, payload)
