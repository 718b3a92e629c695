"""The aiomqtt fast path against the installed aiomqtt and a real mosquitto.

These tests fail when aiomqtt's internals that `aiomqtt_fastpath` relies on change (or its
own reader starts reading everything itself): then re-read aiomqtt's client.py against
the module doc of plmarl_sitl/deploy/mqtt/aiomqtt_fastpath.py and, if it still holds, add
the version to VERIFIED_VERSIONS.
"""

from __future__ import annotations

import array
import asyncio
import fcntl
import logging
import os
import shutil
import socket
import termios
import time

import aiomqtt
import pytest

from plmarl_sitl.deploy.mqtt import aiomqtt_fastpath
from plmarl_sitl.deploy.mqtt.transport import NO_DELAY, MqttBus
from plmarl_sitl.sitl.network.broker import MosquittoBroker

pytestmark = [
    pytest.mark.timeout(60),
    pytest.mark.skipif(not shutil.which("mosquitto") and not os.path.exists("/usr/sbin/mosquitto"),
                       reason="mosquitto not installed"),
]

N_BURST = 20
TOPIC_LEN, PAYLOAD_LEN = 4, 8  # "t/00", 8 bytes
PUBLISH_BYTES = 2 + 2 + TOPIC_LEN + PAYLOAD_LEN  # QoS 0 PUBLISH: header, length, topic length, topic, payload


def test_the_installed_aiomqtt_is_the_verified_one() -> None:
    async def main() -> list[str]:
        return aiomqtt_fastpath.mismatches(aiomqtt.Client("127.0.0.1"))

    assert asyncio.run(main()) == []


@pytest.fixture
def broker():  # noqa: ANN201
    with MosquittoBroker() as b:
        yield b


def _pending_bytes(sock: socket.socket) -> int:
    buf = array.array("i", [0])
    fcntl.ioctl(sock.fileno(), termios.FIONREAD, buf)
    return buf[0]


def _burst_while_the_loop_is_blocked(broker: MosquittoBroker, sock: socket.socket) -> None:
    """Publish N_BURST messages from a blocking MQTT 3.1.1 client (raw packets), and return,
    without ever yielding to the event loop, once all of them wait in `sock`'s receive buffer."""
    with socket.create_connection((broker.host, broker.port), timeout=5.0) as pub:
        pub.sendall(b"\x10\x0f\x00\x04MQTT\x04\x02\x00\x3c\x00\x03pub")  # CONNECT, clean session
        assert pub.recv(4) == b"\x20\x02\x00\x00"  # CONNACK, accepted
        pub.sendall(b"".join(b"\x30" + bytes([PUBLISH_BYTES - 2]) + b"\x00\x04" + f"t/{i:02d}".encode() + b"x" * PAYLOAD_LEN
                             for i in range(N_BURST)))
        pub.sendall(b"\xe0\x00")  # DISCONNECT
    deadline = time.monotonic() + 5.0
    while _pending_bytes(sock) < N_BURST * PUBLISH_BYTES:
        assert time.monotonic() < deadline, f"only {_pending_bytes(sock)} bytes arrived"
        time.sleep(0.001)


async def _read_after_a_burst(broker: MosquittoBroker, fast: bool) -> int:
    """Messages aiomqtt holds after three event-loop turns, the burst waiting at once."""
    async with aiomqtt.Client(broker.host, broker.port, socket_options=[NO_DELAY]) as client:
        await client.subscribe("t/#")
        sock = aiomqtt_fastpath.raw_socket(client)
        assert sock is not None
        assert sock.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY) != 0
        if fast:
            assert aiomqtt_fastpath.read_all_per_wakeup(client)
        _burst_while_the_loop_is_blocked(broker, sock)
        for _ in range(3):
            await asyncio.sleep(0)
        return len(client.messages)


def test_every_waiting_packet_is_read_in_one_wakeup(broker: MosquittoBroker) -> None:
    assert asyncio.run(_read_after_a_burst(broker, fast=True)) == N_BURST


def test_aiomqtt_alone_reads_one_packet_per_turn(broker: MosquittoBroker) -> None:
    """Why the fast path exists; if this fails, aiomqtt reads everything itself now."""
    assert asyncio.run(_read_after_a_burst(broker, fast=False)) <= 3


def test_a_broken_connection_ends_the_message_stream(broker: MosquittoBroker) -> None:
    async def main() -> None:
        async with aiomqtt.Client(broker.host, broker.port) as client:
            await client.subscribe("t/#")
            assert aiomqtt_fastpath.read_all_per_wakeup(client)
            broker.stop()
            with pytest.raises(aiomqtt.MqttError):
                async with asyncio.timeout(5.0):
                    await anext(client.messages)
        aiomqtt_fastpath.retrieve_disconnection(client)

    asyncio.run(main())


async def _delivered_after_a_burst(broker: MosquittoBroker) -> tuple[list[tuple[str | None, bytes]], int]:
    """Messages handed to the callback after two event-loop turns, the burst waiting at once,
    and the number aiomqtt's own queue holds then."""
    got: list[tuple[str | None, bytes]] = []
    async with aiomqtt.Client(broker.host, broker.port, socket_options=[NO_DELAY]) as client:
        assert aiomqtt_fastpath.read_all_per_wakeup(client)
        assert aiomqtt_fastpath.deliver_in_reader(client, lambda t, p: got.append((t, p)))
        await client.subscribe("t/#")
        sock = aiomqtt_fastpath.raw_socket(client)
        assert sock is not None
        _burst_while_the_loop_is_blocked(broker, sock)
        for _ in range(2):  # this task's turn, then the one whose select sees the socket readable
            await asyncio.sleep(0)
        return list(got), len(client.messages)


def test_every_waiting_message_is_delivered_in_the_reader_callback(broker: MosquittoBroker) -> None:
    """Issue 25.1: no task wakes per message; in order, and none left for aiomqtt's queue."""
    got, queued = asyncio.run(_delivered_after_a_burst(broker))
    assert got == [(f"t/{i:02d}", b"x" * PAYLOAD_LEN) for i in range(N_BURST)]
    assert queued == 0


def test_a_broken_connection_ends_the_direct_delivery(broker: MosquittoBroker) -> None:
    """`disconnected` raises the MqttError the message stream would; a cancelled wait for it
    leaves the connection's future alone (a second wait still sees the break)."""
    async def main() -> None:
        async with aiomqtt.Client(broker.host, broker.port) as client:
            assert aiomqtt_fastpath.read_all_per_wakeup(client)
            assert aiomqtt_fastpath.deliver_in_reader(client, lambda t, p: None)
            await client.subscribe("t/#")
            first = asyncio.create_task(aiomqtt_fastpath.disconnected(client))
            await asyncio.sleep(0.05)
            first.cancel()
            await asyncio.gather(first, return_exceptions=True)
            assert not client._disconnected.done()  # the connection's own future, as aiomqtt keeps it
            broker.stop()
            with pytest.raises(aiomqtt.MqttError):
                async with asyncio.timeout(5.0):
                    await aiomqtt_fastpath.disconnected(client)
        aiomqtt_fastpath.retrieve_disconnection(client)

    asyncio.run(main())


def test_an_unverified_aiomqtt_falls_back_to_its_own_reader(
    broker: MosquittoBroker, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """Another version: nothing private is touched, one INFO line says why, the bus works."""
    monkeypatch.setattr(aiomqtt, "__version__", "0.0-unverified")
    caplog.set_level(logging.INFO, logger="plmarl.bus")

    async def main() -> list[bytes]:
        got: list[bytes] = []
        sub = MqttBus(broker.url, "sub", ["t/#"], lambda t, p: got.append(p), name="sub")
        pub = MqttBus(broker.url, "pub", [], lambda t, p: None, name="pub")
        tasks = [asyncio.create_task(sub.run()), asyncio.create_task(pub.run())]
        try:
            async with asyncio.timeout(10.0):
                while not (sub.connected.is_set() and pub.connected.is_set()):
                    await asyncio.sleep(0.01)
                for i in range(N_BURST):
                    assert pub.publish(f"t/{i:02d}", bytes([i]))
                while len(got) < N_BURST:
                    await asyncio.sleep(0.01)
        finally:
            for t in tasks:
                t.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
        return got

    assert asyncio.run(main()) == [bytes([i]) for i in range(N_BURST)]
    off = [r for r in caplog.records if "fast path off" in r.getMessage()]
    assert len(off) == 1 and off[0].levelno == logging.INFO  # two clients, two sessions each at least: logged once
    assert "0.0-unverified" in off[0].getMessage()


async def _writer_left_on_a_reused_descriptor(broker: MosquittoBroker, guarded: bool) -> bool:
    """paho asks (from another thread, as from aiomqtt's connect executor) to register its
    socket for writing; before the loop runs that, paho closes the socket and a new socket
    takes its descriptor number. True if a writer is then registered on that descriptor."""
    import threading

    async with aiomqtt.Client(broker.host, broker.port) as client:
        if guarded:
            assert aiomqtt_fastpath.guard_socket_writes(client)
        paho = client._client
        sock = paho.socket()
        fd = sock.fileno()
        asking = threading.Thread(target=lambda: paho.on_socket_register_write(paho, None, sock))
        asking.start()
        asking.join()  # the registration now waits in the loop's queue
        paho.disconnect()
        paho.loop_write()  # paho writes DISCONNECT and closes the socket, in this (the loop's) thread
        assert paho.socket() is None
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as reused:
            if reused.fileno() != fd:
                pytest.skip("the kernel did not reuse the descriptor number")
            for _ in range(3):
                await asyncio.sleep(0)
            return asyncio.get_running_loop().remove_writer(fd)


def test_a_registration_racing_a_close_leaves_no_writer(broker: MosquittoBroker) -> None:
    """Issue 27: a stalled broker stopped the SITL world (EBADF from add_writer; a writer on a
    reused descriptor spins the loop). aiomqtt's own registration reproduces it; the guard not."""
    assert asyncio.run(_writer_left_on_a_reused_descriptor(broker, guarded=False)) is True
    assert asyncio.run(_writer_left_on_a_reused_descriptor(broker, guarded=True)) is False


def test_a_stopped_broker_never_stalls_the_loop(broker: MosquittoBroker) -> None:
    """SIGSTOP the broker while publishing: the bus notices, the event loop keeps its pace
    (no callback spins), and after SIGCONT the bus connects again and delivers."""
    import signal

    async def main() -> tuple[float, int]:
        got: list[bytes] = []
        bus = MqttBus(broker.url, "pub", ["s/#"], lambda t, p: got.append(p), name="pub", keepalive_s=1,
                      backoff_max_s=0.5)
        task = asyncio.create_task(bus.run())
        await asyncio.wait_for(bus.connected.wait(), 5)
        worst, t_prev = 0.0, time.monotonic()
        pid = broker.proc.pid
        os.kill(pid, signal.SIGSTOP)
        try:
            t_end = time.monotonic() + 4.0
            while time.monotonic() < t_end:
                bus.publish("s/x", b"y" * 64)
                await asyncio.sleep(0.005)
                now = time.monotonic()
                worst, t_prev = max(worst, now - t_prev), now
        finally:
            os.kill(pid, signal.SIGCONT)
        before = len(got)
        deadline = time.monotonic() + 10
        while len(got) <= before and time.monotonic() < deadline:
            bus.publish("s/x", b"z")
            await asyncio.sleep(0.05)
        task.cancel()
        await asyncio.gather(task, return_exceptions=True)
        return worst, len(got) - before

    worst, delivered = asyncio.run(main())
    assert worst < 0.5, f"the event loop stalled {worst:.2f} s"
    assert delivered > 0


def test_a_retained_message_reaches_the_callback_once_the_bus_is_connected(broker: MosquittoBroker) -> None:
    """The reader delivers the retained messages while the session still subscribes; the bus
    holds them until it serves, so its callback sees a connected bus (as aiomqtt's queue did)."""
    async def main() -> list[tuple[str, bytes, bool]]:
        pub = MqttBus(broker.url, "pub", [], lambda t, p: None, name="pub")
        task = asyncio.create_task(pub.run())
        await asyncio.wait_for(pub.connected.wait(), 5)
        pub.publish("r/x", b"kept", sticky=True)
        got: list[tuple[str, bytes, bool]] = []
        sub = MqttBus(broker.url, "sub", ["r/#"], lambda t, p: got.append((t, p, sub.connected.is_set())), name="sub")
        tasks = [task, asyncio.create_task(sub.run())]
        try:
            async with asyncio.timeout(10.0):
                while not got:
                    await asyncio.sleep(0.01)
        finally:
            for t in tasks:
                t.cancel()
            await asyncio.gather(*tasks, return_exceptions=True)
        return got

    assert asyncio.run(main()) == [("r/x", b"kept", True)]
