"""Every use of aiomqtt's private state, in one place, checked against the aiomqtt it runs on.

aiomqtt has no public hook for its socket reader, and its reader has paho read one MQTT
packet per event-loop turn. In a loop that is busy between yields (the SITL world steps
20 vehicles per chunk) the 20 updates of a signalling instant then took 20 turns, 10-15 ms
each at 15x: the last arrived 3 s of vehicle time late (docs/RESULTS.md, commit 499f10d).
`read_all_per_wakeup` replaces that reader with one that reads every packet waiting,
`deliver_in_reader` hands each message to the bus's callback right there (aiomqtt queues it
for `client.messages`, whose every step is a task, an `asyncio.wait` and three event-loop
turns: ~4 loop callbacks per message, issue 25.1), and `guard_socket_writes` makes its
socket-writer registration safe against a closed socket.

What this relies on, read in aiomqtt 2.5.1's client.py (`Client.__init__`,
`_on_socket_open`, `_on_socket_close`, `__aexit__`, `MessagesIterator.__anext__`):
  - `Client._client` is the paho-mqtt client (whose `socket()` and `loop_read()` are
    paho's public API);
  - `Client._disconnected` is the future that ends `client.messages` with an MqttError
    when the connection breaks (done with an exception), or is closed (a result);
  - aiomqtt takes incoming messages only through paho's `on_message` callback (paho's
    public API), which it sets once in `Client.__init__` to put them in its queue;
  - aiomqtt's reader is a `loop.add_reader` callback on the paho socket's descriptor, so
    adding ours on the same descriptor replaces it, and aiomqtt's `remove_reader` on
    socket close removes ours.
When the aiomqtt version is not one of VERIFIED_VERSIONS or the attributes are not what
they were, nothing here touches the client: aiomqtt's own (slower) reader stays, and that
is logged once at INFO. tests/deploy/test_mqtt_fastpath.py fails when they change, so an
upgrade is noticed in CI rather than as a silently slower SITL.
"""

from __future__ import annotations

import asyncio
import logging
import select
import socket
import threading
from collections.abc import Callable

import aiomqtt
import paho.mqtt.client as mqtt

log = logging.getLogger("plmarl.bus")

VERIFIED_VERSIONS = ("2.5.1",)  # aiomqtt versions whose internals were read and tested as above
MAX_READS_PER_WAKEUP = 256

_logged: set[str] = set()  # mismatches already reported: each is logged once per process


def mismatches(client: aiomqtt.Client) -> list[str]:
    """What about this aiomqtt differs from what the fast path relies on (empty: nothing)."""
    found = []
    if aiomqtt.__version__ not in VERIFIED_VERSIONS:
        found.append(f"aiomqtt {aiomqtt.__version__} is not a verified version ({', '.join(VERIFIED_VERSIONS)})")
    if not isinstance(getattr(client, "_client", None), mqtt.Client):
        found.append("aiomqtt.Client._client is not a paho-mqtt client")
    if not isinstance(getattr(client, "_disconnected", None), asyncio.Future):
        found.append("aiomqtt.Client._disconnected is not a future")
    return found


def _usable(client: aiomqtt.Client) -> bool:
    found = "; ".join(mismatches(client))
    if found and found not in _logged:
        _logged.add(found)
        log.info("MQTT fast path off, aiomqtt's own reader (one packet per event-loop turn) is used: %s", found)
    return not found


def raw_socket(client: aiomqtt.Client) -> socket.socket | None:
    """The connection's plain TCP socket (None: not connected, websockets or TLS, or an
    aiomqtt this module does not know)."""
    if not _usable(client):
        return None
    sock = client._client.socket()
    if type(sock) is not socket.socket or sock.fileno() < 0:
        return None  # websockets or TLS buffer bytes that select cannot see
    return sock


def read_all_per_wakeup(client: aiomqtt.Client) -> bool:
    """Call once connected: from now on every MQTT packet waiting on the socket is read each
    time it turns readable. False when aiomqtt's own reader is kept (see the module doc).
    A broken connection ends the session as aiomqtt's own reader does."""
    sock = raw_socket(client)
    if sock is None:
        return False
    paho, gone, fd = client._client, client._disconnected, sock.fileno()

    def read_all() -> None:
        try:
            for _ in range(MAX_READS_PER_WAKEUP):
                if paho.loop_read() != mqtt.MQTT_ERR_SUCCESS or paho.socket() is None:
                    return
                if not select.select([fd], [], [], 0)[0]:
                    return
        except Exception as exc:  # noqa: BLE001 - as aiomqtt: an error here is a broken connection
            if not gone.done():
                gone.set_exception(exc)

    asyncio.get_running_loop().add_reader(fd, read_all)  # replaces aiomqtt's reader for fd
    return True


def deliver_in_reader(client: aiomqtt.Client, handler: Callable[[str | None, bytes], None]) -> bool:
    """Call once connected, before subscribing: from now on each incoming message is handed to
    `handler(topic, payload)` (topic None: not UTF-8) as paho parses it, in the socket reader's
    callback, in arrival order; `client.messages` then yields nothing: wait for the end of the
    connection with `disconnected`. `handler` must not block, and must not raise (what it
    raises breaks the connection, as a failure in aiomqtt's own reader would). False when the
    client is not one this module knows (aiomqtt's queue stays)."""
    if not _usable(client):
        return False

    def on_message(_client: mqtt.Client, _userdata: object, message: mqtt.MQTTMessage) -> None:
        try:
            topic = message.topic
        except UnicodeDecodeError:
            topic = None
        handler(topic, message.payload)

    client._client.on_message = on_message  # replaces aiomqtt's `_on_message` (its queue)
    return True


async def disconnected(client: aiomqtt.Client) -> None:
    """Wait for the connection to end (with `deliver_in_reader`, in place of iterating
    `client.messages`); raises the MqttError the message stream would end with. Cancelling
    the wait leaves the connection's own future alone."""
    gone = client._disconnected
    await asyncio.wait([gone])  # not `await gone`: a cancelled waiter would cancel it
    raise aiomqtt.MqttError("Disconnected during message iteration") from (None if gone.cancelled() else gone.exception())


def guard_socket_writes(client: aiomqtt.Client) -> bool:
    """Call once connected: paho's "register the socket for writing" is applied at once in
    the event loop's thread, and only to the socket paho still holds.

    Why (issue 27, a stalled broker stopped the SITL world): aiomqtt 2.5.1 registers the
    writer with `loop.call_soon_threadsafe(loop.add_writer, sock.fileno(), ...)`, the
    descriptor number read when paho asks. When paho closes that socket before the loop
    runs the call (a keepalive timeout while the broker is stopped; a busy loop makes the
    window wide), the writer is added to a closed descriptor (`OSError: [Errno 9] Bad file
    descriptor` from `add_writer`, logged by asyncio), or to a new socket that reused its
    number: paho's `loop_write` on its closed connection then returns at once without
    unregistering, a writable socket wakes the selector on every turn, and the loop spins
    in that callback while physics and telemetry wait. False when the client is not one
    this module knows (aiomqtt's own callbacks stay)."""
    sock = raw_socket(client)
    if sock is None:
        return False
    paho, gone = client._client, client._disconnected
    loop = asyncio.get_running_loop()
    loop_thread = threading.get_ident()

    def write() -> None:
        try:
            paho.loop_write()
        except Exception as exc:  # noqa: BLE001 - as aiomqtt: a broken connection
            if not gone.done():
                gone.set_exception(exc)

    def register(_client: mqtt.Client, _userdata: object, s: socket.socket) -> None:
        def add() -> None:
            if paho.socket() is s and s.fileno() >= 0:  # still paho's open connection
                loop.add_writer(s.fileno(), write)
        if threading.get_ident() == loop_thread:
            add()
        else:  # paho connecting in aiomqtt's executor thread
            loop.call_soon_threadsafe(add)

    def unregister(_client: mqtt.Client, _userdata: object, s: socket.socket) -> None:
        if s.fileno() >= 0:
            loop.remove_writer(s.fileno())

    paho.on_socket_register_write = register
    paho.on_socket_unregister_write = unregister
    return True


def retrieve_disconnection(client: aiomqtt.Client) -> None:
    """Call after the client's context has exited. aiomqtt keeps an unexpected
    disconnection's error in a future that its `__aexit__` returns early on without reading;
    unread, asyncio prints "Future exception was never retrieved" at exit (e.g. after
    Ctrl-C). Reading it here keeps the exit quiet."""
    if not _usable(client):
        return
    gone = client._disconnected
    if gone.done() and not gone.cancelled():
        gone.exception()
    else:
        # Not yet: a connect attempt abandoned while the broker was stopped (timed out) can
        # still be ended by paho later, after this session is over; read it then.
        gone.add_done_callback(lambda f: f.cancelled() or f.exception())
