"""MQTT transport over real brokers (amqtt in-process, mosquitto child), and link URLs."""

from __future__ import annotations

import asyncio
import shutil
import time

import pytest

from plmarl_sitl.deploy.mavlink.connect import connect
from plmarl_sitl.deploy.mqtt.transport import MqttBus
from plmarl_sitl.sitl.autopilot.host import AutopilotHost
from plmarl_sitl.sitl.network.broker import EmbeddedBroker, MosquittoBroker, free_port, free_udp_ports

pytestmark = [pytest.mark.timeout(60), pytest.mark.integration]


async def _wait(cond, timeout: float = 5.0) -> None:  # noqa: ANN001
    async with asyncio.timeout(timeout):
        while not cond():
            await asyncio.sleep(0.01)


async def _pubsub(url: str) -> None:
    got: list[tuple[str, bytes]] = []
    sub = MqttBus(url, "sub", ["t/#"], lambda t, p: got.append((t, p)), name="sub")
    pub = MqttBus(url, "pub", [], lambda t, p: None, name="pub")
    async with asyncio.TaskGroup() as tg:
        tasks = [tg.create_task(sub.run(), name="sub"), tg.create_task(pub.run(), name="pub")]
        await _wait(lambda: sub.connected.is_set() and pub.connected.is_set())
        for i in range(20):
            assert pub.publish(f"t/{i}", bytes([i]))
        await _wait(lambda: len(got) == 20)
        assert got[5] == ("t/5", b"\x05")
        for t in tasks:
            t.cancel()


async def _clock(host) -> None:  # noqa: ANN001 - an AutopilotHost
    """Drive a host's sim clock at about 2x real time until cancelled."""
    while True:
        host.advance(0.02)
        await asyncio.sleep(0.01)


def test_pubsub_amqtt() -> None:
    async def main() -> None:
        async with EmbeddedBroker() as b:
            await _pubsub(b.url)

    asyncio.run(main())


@pytest.mark.skipif(not shutil.which("mosquitto") and not __import__("os").path.exists("/usr/sbin/mosquitto"),
                    reason="mosquitto not installed")
def test_pubsub_mosquitto_and_reconnect() -> None:
    """Broker dies: publishing drops (counted), the bus reconnects with backoff, sticky
    messages are re-sent and subscriptions restored."""
    port = free_port()

    async def main() -> None:
        b = MosquittoBroker(port=port)
        b.start()
        try:
            got: list[tuple[str, bytes]] = []
            sub = MqttBus(b.url, "sub", ["t/#"], lambda t, p: got.append((t, p)), name="sub", backoff_max_s=0.5)
            pub = MqttBus(b.url, "pub", [], lambda t, p: None, name="pub", backoff_max_s=0.5)
            async with asyncio.TaskGroup() as tg:
                tasks = [tg.create_task(sub.run(), name="sub"), tg.create_task(pub.run(), name="pub")]
                await _wait(lambda: sub.connected.is_set() and pub.connected.is_set())
                pub.publish("t/sticky", b"s", sticky=True)
                await _wait(lambda: ("t/sticky", b"s") in got)
                b.stop()
                await _wait(lambda: not pub.connected.is_set() and not sub.connected.is_set())
                assert not pub.publish("t/lost", b"x")
                assert pub.stats.dropped_offline >= 1
                b.start()
                await _wait(lambda: sub.connected.is_set() and pub.connected.is_set(), 10)
                assert sub.stats.connects == 2 and sub.stats.disconnects == 1
                pub.publish("t/after", b"y")
                await _wait(lambda: ("t/after", b"y") in got)
                assert ("t/lost", b"x") not in got
                for t in tasks:
                    t.cancel()
        finally:
            b.stop()

    asyncio.run(main())


def test_handler_errors_do_not_kill_the_bus() -> None:
    async def main() -> None:
        async with EmbeddedBroker() as b:
            seen: list[str] = []

            def handler(topic: str, payload: bytes) -> None:
                seen.append(topic)
                if payload == b"boom":
                    raise ValueError("bad")

            sub = MqttBus(b.url, "sub", ["t/#"], handler, name="sub")
            pub = MqttBus(b.url, "pub", [], lambda t, p: None, name="pub")
            async with asyncio.TaskGroup() as tg:
                tasks = [tg.create_task(sub.run(), name="sub"), tg.create_task(pub.run(), name="pub")]
                await _wait(lambda: sub.connected.is_set() and pub.connected.is_set())
                pub.publish("t/1", b"boom")
                pub.publish("t/2", b"ok")
                await _wait(lambda: "t/2" in seen)
                assert sub.stats.disconnects == 0
                for t in tasks:
                    t.cancel()

    asyncio.run(main())


def test_udpin_link_learns_the_vehicle() -> None:
    """udpin://: the autopilot speaks first (here: its GCS stream), we answer it."""

    async def main() -> None:
        gcs_port = free_port()
        host = AutopilotHost(1, base_port=free_udp_ports(1), gcs=("127.0.0.1", gcs_port))
        await host.start()

        task = asyncio.create_task(_clock(host), name="clock")
        link = connect(f"udpin://127.0.0.1:{gcs_port}")
        link.stamp_arrivals = True
        try:
            await link.open(timeout=5)
            assert link.personality is not None and link.personality.name == "px4"
            await link.set_message_interval("LOCAL_POSITION_NED", 20)  # a command round trip
            # Every message carries its datagram's kernel receive time (CLOCK_REALTIME).
            before = time.time_ns()
            m = await link.recv("LOCAL_POSITION_NED", 3.0)
            assert before - 60_000_000 <= m.rx_ns <= time.time_ns()
            link.stamp_arrivals = False
            await link.recv("LOCAL_POSITION_NED", 3.0)
            assert not hasattr(await link.recv("LOCAL_POSITION_NED", 3.0), "rx_ns")
        finally:
            link.close()
            task.cancel()
            host.close()

    asyncio.run(main())


def test_tcpout_link_through_a_stream_bridge() -> None:
    """tcpout://: frames arrive glued and split across TCP reads; the stream parser copes.
    A small bridge relays TCP <-> the emulator's UDP port (as a telemetry radio would)."""

    async def main() -> None:
        base = free_udp_ports(1)
        host = AutopilotHost(1, base_port=base)
        await host.start()
        loop = asyncio.get_running_loop()

        class Up(asyncio.DatagramProtocol):
            def __init__(self, writer: asyncio.StreamWriter) -> None:
                self.writer = writer

            def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
                # Split every datagram in two writes: frames must survive arbitrary chunking.
                self.writer.write(data[:7])
                self.writer.write(data[7:])

        async def bridge(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            udp, _ = await loop.create_datagram_endpoint(lambda: Up(writer), remote_addr=("127.0.0.1", base))
            try:
                while data := await reader.read(4096):
                    udp.sendto(data)  # our client writes whole frames per send
            finally:
                udp.close()

        server = await asyncio.start_server(bridge, "127.0.0.1", 0)
        port = server.sockets[0].getsockname()[1]

        task = asyncio.create_task(_clock(host), name="clock")
        link = connect(f"tcpout://127.0.0.1:{port}")
        try:
            await link.open(timeout=5)
            assert link.personality is not None and link.personality.name == "px4"
            await link.set_message_interval("LOCAL_POSITION_NED", 20)
            m = await link.recv("LOCAL_POSITION_NED", 3.0)
            assert m.time_boot_ms > 0
        finally:
            link.close()
            task.cancel()
            server.close()
            host.close()

    asyncio.run(main())
