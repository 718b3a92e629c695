"""What the SITL world sends the agents over its bus, and the broker outage lockstep emulates.

A free-running swarm's broker outage is real: the launcher's gate cuts the broker's TCP
connections, and the agents reconnect with a jittered wall-clock backoff, so which seconds
each one misses depends on machine load. A lockstep world must be deterministic, so it
emulates the outage instead: for the outage's mission seconds no sensing and no relayed
state reaches an agent, and retained messages (the demand map, T_up changes) are held and
go out when it ends, as a broker's retained copy reaches a reconnecting agent. The
lockstep tick is the SITL clock, not signalling, and goes on (`publish_sticky`).
"""

from __future__ import annotations

from plmarl_sitl.deploy.mqtt.transport import MqttBus
from plmarl_sitl.model.events import EventSchedule


class Outbox:
    def __init__(self, bus: MqttBus, emulated_outages: EventSchedule | None) -> None:
        """`emulated_outages`: the schedule whose broker outages this world emulates
        (lockstep), or None (free-running: the broker itself goes down)."""
        self.bus = bus
        self.schedule = emulated_outages
        self.cut = False  # this mission second lies in an emulated outage
        self._held_retained: dict[str, bytes] = {}  # retained messages it holds (topic -> newest)

    def outage_at(self, k: int) -> bool:
        """Mission second k lies in an emulated broker outage."""
        return self.schedule is not None and self.schedule.broker_down(k)

    def begin_second(self, k: int) -> None:
        """Mission second k begins: in an outage or not; at its end the held retained go out."""
        self.cut = self.outage_at(k)
        if not self.cut:
            for topic, payload in self._held_retained.items():
                self.bus.publish(topic, payload, sticky=True)
            self._held_retained.clear()

    def publish(self, topic: str, payload: bytes) -> None:
        self.bus.publish(topic, payload)

    def publish_sticky(self, topic: str, payload: bytes) -> None:
        """A retained message no outage holds back (start, tick, the clearing of a previous run's)."""
        self.bus.publish(topic, payload, sticky=True)

    def publish_retained(self, topic: str, payload: bytes) -> None:
        """A retained message, held while an emulated outage lasts."""
        if self.cut:
            self._held_retained[topic] = payload  # the newest per topic, as a broker retains
        else:
            self.bus.publish(topic, payload, sticky=True)

    @property
    def connected(self) -> bool:
        return self.bus.connected.is_set()
