"""The broker gate on real sockets: an outage looks like a stopped broker (refused), then it relays again."""

from __future__ import annotations

import asyncio

import pytest

from plmarl_sitl.sitl.network.broker_gate import BrokerGate


async def _echo(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
    while data := await reader.read(1024):
        writer.write(data)
        await writer.drain()
    writer.close()


async def _round_trip(port: int, payload: bytes) -> bytes:
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    writer.write(payload)
    await writer.drain()
    got = await asyncio.wait_for(reader.readexactly(len(payload)), 2)
    writer.close()
    return got


def test_outage_refuses_connections_then_relays_on_the_same_port() -> None:
    async def main() -> None:
        upstream = await asyncio.start_server(_echo, "127.0.0.1", 0)
        gate = BrokerGate("127.0.0.1", upstream.sockets[0].getsockname()[1])
        await gate.start()
        port = gate.port
        try:
            assert await _round_trip(port, b"before") == b"before"
            reader, writer = await asyncio.open_connection("127.0.0.1", port)
            writer.write(b"x")
            assert await asyncio.wait_for(reader.readexactly(1), 2) == b"x"

            gate.outage(True)
            # The relayed connection is closed, and a new one is refused at once, as by a stopped broker
            # (an accept-then-close would leave an MQTT client waiting for its CONNACK).
            assert await asyncio.wait_for(reader.read(10), 2) == b""
            with pytest.raises(ConnectionRefusedError):
                await asyncio.open_connection("127.0.0.1", port)

            gate.outage(False)
            assert gate.port == port
            assert await _round_trip(port, b"after") == b"after"
        finally:
            await gate.close()
            upstream.close()

    asyncio.run(main())
