"""MQTT transport on aiomqtt: one connection, reconnect with backoff, non-blocking publish.

`MqttBus.run()` is a task that owns the connection for the life of the process. While
connected it subscribes, drains the outgoing queue and hands every incoming message to
`on_message(topic, payload)` (a plain callback: it must not block). When the broker goes
away it waits an exponentially growing, jittered delay and connects again; callers are
never blocked and keep working on what they have (the agent flies on its predictions).

Publishing while disconnected drops the message and counts it: signalling states are
useless once stale. `publish(..., sticky=True)` messages (retained announcements such as
the mission start) are re-sent after every reconnect instead.
"""

from __future__ import annotations

import asyncio
import logging
import random
import socket
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import aiomqtt

from plmarl_sitl.deploy.mqtt import aiomqtt_fastpath
from plmarl_sitl.deploy.mqtt.url import parse_broker_url

log = logging.getLogger("plmarl.bus")
# aiomqtt's logger warns once more than 10 publishes are pending; `_sender` hands it whole
# batches on purpose, and a lost connection is reported by our own logger.
logging.getLogger("mqtt").setLevel(logging.ERROR)

OnMessage = Callable[[str, bytes], None]
UNREACHABLE_REPEAT_S = 30.0  # wall: how often a broker still unreachable is said again
SEND_BATCH = 256  # most messages handed to the client per write round trip


@dataclass
class BusStats:
    connects: int = 0
    disconnects: int = 0
    published: int = 0
    dropped_offline: int = 0
    dropped_queue_full: int = 0
    received: int = 0
    bad_payload_type: int = 0
    bad_topic: int = 0  # not UTF-8 (a broker refuses those: never seen)

    def as_dict(self) -> dict[str, int]:
        return dict(self.__dict__)


# TCP_NODELAY on the broker connection. paho leaves Nagle's algorithm on, so a small publish
# right after another waits for the broker's delayed ACK (40 ms on Linux): at 15x that put
# 0.6 s of vehicle time on each hop of a signalling instant.
NO_DELAY = (socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)


class MqttBus:
    def __init__(
        self,
        url: str,
        client_id: str,
        subscriptions: Sequence[str],
        on_message: OnMessage,
        *,
        backoff_min_s: float = 0.1,
        backoff_max_s: float = 5.0,
        connect_timeout_s: float = 3.0,
        keepalive_s: int = 5,
        queue_size: int = 1024,
        name: str = "bus",
        credentials: tuple[str, str] | None = None,
    ) -> None:
        self.host, self.port = parse_broker_url(url)
        self.url = url
        self.client_id = client_id
        self.subscriptions = list(subscriptions)
        self.on_message = on_message
        self.backoff_min_s, self.backoff_max_s = backoff_min_s, backoff_max_s
        self.connect_timeout_s = connect_timeout_s
        self.keepalive_s = keepalive_s
        self.name = name
        self.credentials = credentials  # (username, password) the broker knows this client by
        self.connected = asyncio.Event()
        self.on_connection: Callable[[bool], None] | None = None  # told when the connection comes up or goes
        self.stats = BusStats()
        self._queue: asyncio.Queue[tuple[str, bytes, bool]] = asyncio.Queue(queue_size)
        self._sticky: dict[str, bytes] = {}
        self._rng = random.Random()
        # Messages the reader delivers while the session still subscribes (retained ones): held
        # until it serves, so `on_message` sees them once the bus is connected, as before.
        self._held: list[tuple[str | None, object]] | None = None
        self._was_connected = False
        self._unreachable_since: float | None = None  # monotonic s of the first failure of a streak
        self._unreachable_logged = 0.0

    @property
    def queued(self) -> int:
        """Messages published but not yet handed to the broker connection."""
        return self._queue.qsize()

    # ------------------------------------------------------------------ publishing
    def publish(self, topic: str, payload: bytes, *, retain: bool = False, sticky: bool = False) -> bool:
        """Queue a QoS 0 message; False (and counted) if it was dropped."""
        if sticky:
            self._sticky[topic] = payload
            retain = True
        if not self.connected.is_set():
            self.stats.dropped_offline += 1
            return False
        try:
            self._queue.put_nowait((topic, payload, retain))
        except asyncio.QueueFull:
            self.stats.dropped_queue_full += 1
            return False
        return True

    # ------------------------------------------------------------------ connection
    def _set_connected(self, up: bool) -> None:
        was = self.connected.is_set()
        if up:
            self.connected.set()
        else:
            self.connected.clear()
        if was != up and self.on_connection is not None:
            self.on_connection(up)

    async def run(self) -> None:
        """Connect, serve, reconnect with backoff; returns only when cancelled."""
        delay = self.backoff_min_s
        while True:
            try:
                await self._session()
            except (aiomqtt.MqttError, OSError) as exc:  # OSError: a socket call on a connection that broke
                if self._was_connected:
                    log.warning("%s: lost broker %s (%s); reconnecting", self.name, self.url, exc)
                    delay = self.backoff_min_s
                    self._unreachable_since = None
                else:
                    self._unreachable(str(exc))
            except TimeoutError:
                self._set_connected(False)
                self._unreachable("connect timed out")
            # Jittered exponential backoff: a swarm of agents must not reconnect in lockstep.
            await asyncio.sleep(delay * (0.5 + self._rng.random()))
            delay = min(self.backoff_max_s, delay * 2.0)

    def _unreachable(self, why: str) -> None:
        """A failed connection attempt: a WARNING the first time (a wrong broker host must not
        be silent), again every UNREACHABLE_REPEAT_S while it lasts, DEBUG in between."""
        now = time.monotonic()
        if self._unreachable_since is None or now - self._unreachable_logged >= UNREACHABLE_REPEAT_S:
            first = self._unreachable_since is None
            self._unreachable_since = self._unreachable_since or now
            self._unreachable_logged = now
            log.warning("%s: cannot reach the MQTT broker at %s (%s)%s; retrying every %g s at most", self.name, self.url,
                        why, "" if first else f" for {now - self._unreachable_since:.0f} s", self.backoff_max_s)
        else:
            log.debug("%s: cannot reach broker %s (%s)", self.name, self.url, why)

    async def _session(self) -> None:
        self._was_connected = False
        client = aiomqtt.Client(
            self.host,
            self.port,
            identifier=self.client_id,
            username=self.credentials[0] if self.credentials else None,
            password=self.credentials[1] if self.credentials else None,
            keepalive=self.keepalive_s,
            timeout=self.connect_timeout_s,
            clean_session=True,
            socket_options=[NO_DELAY],
        )
        try:
            async with asyncio.timeout(self.connect_timeout_s * 2) as connecting, client:
                if connecting.expired():
                    # The deadline fired just as the connection completed (a loaded machine), and
                    # Python 3.11's asyncio.wait_for inside aiomqtt swallowed its cancellation: the
                    # timeout cannot be rescheduled any more. A cancellation still pending lands in
                    # the sleep; either way this attempt ends as timed out and run() retries.
                    await asyncio.sleep(0)
                    raise TimeoutError
                if asyncio.current_task().cancelling():  # type: ignore[union-attr]
                    # We were cancelled (stop, Ctrl-C) as the CONNACK came in, and the same
                    # wait_for swallowed it: without this the bus would serve for ever and the
                    # agent's stop would hang.
                    raise asyncio.CancelledError
                connecting.reschedule(None)  # the deadline is on connecting only
                aiomqtt_fastpath.read_all_per_wakeup(client)
                self._held = []
                direct = aiomqtt_fastpath.deliver_in_reader(client, self._deliver)
                aiomqtt_fastpath.guard_socket_writes(client)
                try:
                    await self._serve(client, direct)
                finally:
                    self._was_connected = self.connected.is_set()
                    if self._was_connected:
                        self.stats.disconnects += 1
                    self._set_connected(False)
        except aiomqtt.MqttError:
            # Closing a connection whose broker is gone can fail too (aiomqtt's __aexit__
            # raises); while we are being cancelled (Ctrl-C also stops a local broker) that
            # error must not hide the cancellation, or run() would reconnect for ever.
            if asyncio.current_task().cancelling():  # type: ignore[union-attr]
                raise asyncio.CancelledError from None
            raise
        finally:
            aiomqtt_fastpath.retrieve_disconnection(client)

    async def _serve(self, client: aiomqtt.Client, direct: bool) -> None:
        """Subscribe, re-send sticky messages, then send and receive until the connection
        breaks (direct: messages come to `_deliver` from the socket reader)."""
        for topic in self.subscriptions:
            await client.subscribe(topic, qos=0)
        while not self._queue.empty():  # whatever was queued belongs to the old session
            self._queue.get_nowait()
        for topic, payload in self._sticky.items():
            await client.publish(topic, payload, qos=0, retain=True)
        self.stats.connects += 1
        self._set_connected(True)
        self._unreachable_since = None
        log.info("%s: connected to %s", self.name, self.url)
        held, self._held = self._held or [], None
        for topic, payload in held:
            self._deliver(topic, payload)
        # Plain tasks, not a TaskGroup: when the connection breaks while this task is
        # being cancelled (Ctrl-C also stops a local broker), Python 3.11's TaskGroup
        # raises the MqttError and drops the CancelledError, and run() would then
        # reconnect for ever instead of ending.
        workers = [asyncio.create_task(self._sender(client), name=f"{self.name}-sender"),
                   asyncio.create_task(aiomqtt_fastpath.disconnected(client) if direct else self._receiver(client),
                                       name=f"{self.name}-receiver")]
        try:
            done, _ = await asyncio.wait(workers, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for w in workers:
                w.cancel()
            await asyncio.gather(*workers, return_exceptions=True)
        for w in done:
            if not w.cancelled() and w.exception() is not None:
                raise w.exception()  # an MqttError: run() reconnects
        raise aiomqtt.MqttError("message stream ended")

    async def _sender(self, client: aiomqtt.Client) -> None:
        # Publish whatever is queued as one batch: each aiomqtt publish waits for its
        # socket write, an event-loop round trip, and a busy process (the SITL world
        # stepping 20 vehicles) grants few round trips. One at a time, the queue then
        # grows without bound; in a batch, one write callback sends them all.
        while True:
            batch = [await self._queue.get()]
            while len(batch) < SEND_BATCH and not self._queue.empty():
                batch.append(self._queue.get_nowait())
            await asyncio.gather(*(client.publish(t, p, qos=0, retain=r) for t, p, r in batch))
            self.stats.published += len(batch)

    def _deliver(self, topic: str | None, payload: object) -> None:
        """One incoming message to `on_message`: from the socket reader's callback
        (`aiomqtt_fastpath.deliver_in_reader`: no task wakes per message), else from `_receiver`."""
        if self._held is not None:  # the session is not serving yet
            self._held.append((topic, payload))
            return
        self.stats.received += 1
        if topic is None:
            self.stats.bad_topic += 1
            return
        if not isinstance(payload, bytes | bytearray):
            self.stats.bad_payload_type += 1
            return
        try:
            self.on_message(topic, bytes(payload))
        except Exception:  # a bad callback must not take the bus down
            log.exception("%s: message handler failed on %s", self.name, topic)

    async def _receiver(self, client: aiomqtt.Client) -> None:
        """aiomqtt's own message stream (an aiomqtt the fast path does not know)."""
        async for msg in client.messages:
            self._deliver(str(msg.topic), msg.payload)
        raise aiomqtt.MqttError("message stream ended")
