"""MAVLink links over real transports: subscriptions keep every parsed message, and a
serial port that goes away ends the link (logged once) instead of a silent busy loop.

The vehicle side is a pymavlink encoder writing frames by hand into a UDP socket, a TCP
connection or the master end of a pseudo-terminal (the link opens the slave end as its
serial port), so two frames can be put in one datagram or one write on purpose.
"""

from __future__ import annotations

import asyncio
import logging
import os
import re
import socket
import threading
import time

import pytest

from plmarl_sitl.deploy.mavlink.codec import Codec, dialect
from plmarl_sitl.deploy.mavlink.connect import connect
from plmarl_sitl.errors import LinkLost, VehicleTimeout
from plmarl_sitl.sitl.network.broker import free_port

pytestmark = pytest.mark.timeout(60)

d = dialect


class Vehicle:
    """Frames as a PX4 autopilot (sysid 1, component 1) would send them."""

    def __init__(self) -> None:
        self.codec = Codec(1, d.MAV_COMP_ID_AUTOPILOT1)

    def heartbeat(self) -> bytes:
        mav = self.codec.mav
        return self.codec.encode(mav.heartbeat_encode(d.MAV_TYPE_QUADROTOR, d.MAV_AUTOPILOT_PX4, 0, 0, d.MAV_STATE_ACTIVE))

    def position(self, time_boot_ms: int) -> bytes:
        return self.codec.encode(self.codec.mav.local_position_ned_encode(time_boot_ms, 1.0, 2.0, -3.0, 0.0, 0.0, 0.0))

    def two_positions(self) -> bytes:
        """Two frames back to back: one datagram, one stream write."""
        return self.position(100) + self.position(200)


async def _receive_two(link, send) -> list[int]:  # noqa: ANN001 - an open VehicleLink, a callable
    """Both glued frames are parsed in one go, before the subscriber runs again; with a
    one-shot waiter per message the second would be gone by the time it asked."""
    with link.subscribe("LOCAL_POSITION_NED") as sub:
        send()
        first = await sub.next(3.0)
        second = await sub.next(3.0)
    return [first.time_boot_ms, second.time_boot_ms]


def test_two_frames_in_one_datagram_both_reach_the_subscriber() -> None:
    async def main() -> list[int]:
        vehicle, port = Vehicle(), free_port()
        udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        link = connect(f"udpin://127.0.0.1:{port}")
        try:
            opening = asyncio.create_task(link.open(timeout=5.0))
            while not opening.done():  # the vehicle speaks first on udpin
                udp.sendto(vehicle.heartbeat(), ("127.0.0.1", port))
                await asyncio.sleep(0.05)
            await opening
            return await _receive_two(link, lambda: udp.sendto(vehicle.two_positions(), ("127.0.0.1", port)))
        finally:
            link.close()
            udp.close()

    assert asyncio.run(main()) == [100, 200]


def test_two_frames_in_one_tcp_write_both_reach_the_subscriber() -> None:
    async def main() -> list[int]:
        vehicle = Vehicle()
        writers: list[asyncio.StreamWriter] = []

        async def serve(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            writers.append(writer)
            writer.write(vehicle.heartbeat())

        server = await asyncio.start_server(serve, "127.0.0.1", 0)
        link = connect(f"tcpout://127.0.0.1:{server.sockets[0].getsockname()[1]}")
        try:
            await link.open(timeout=5.0)
            return await _receive_two(link, lambda: writers[0].write(vehicle.two_positions()))
        finally:
            link.close()
            server.close()

    assert asyncio.run(main()) == [100, 200]


def test_a_closed_subscription_gets_nothing_and_recv_still_times_out() -> None:
    async def main() -> None:
        vehicle = Vehicle()
        writers: list[asyncio.StreamWriter] = []

        async def serve(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            writers.append(writer)
            writer.write(vehicle.heartbeat())

        server = await asyncio.start_server(serve, "127.0.0.1", 0)
        link = connect(f"tcpout://127.0.0.1:{server.sockets[0].getsockname()[1]}")
        try:
            await link.open(timeout=5.0)
            with pytest.raises(VehicleTimeout, match="no LOCAL_POSITION_NED within 0.2 s"):
                await link.recv("LOCAL_POSITION_NED", 0.2)
            closed = link.subscribe("HEARTBEAT")
            closed.close()
            with link.subscribe("HEARTBEAT") as still_open:
                writers[0].write(vehicle.heartbeat())
                await still_open.next(3.0)
            with pytest.raises(VehicleTimeout):
                await closed.next(0.1)
        finally:
            link.close()
            server.close()

    asyncio.run(main())


def _serial_threads(dev: str) -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name in (f"serial-read-{dev}", f"serial-write-{dev}")]


def test_an_unplugged_serial_port_ends_the_link(caplog: pytest.LogCaptureFixture) -> None:
    """The other end of the pty closes (a USB radio pulled out): one ERROR line naming the
    port, every wait raises LinkLost at once, commands are not retried, both threads end."""
    pytest.importorskip("serial")
    caplog.set_level(logging.INFO, logger="plmarl.mavlink")
    master, slave = os.openpty()
    dev = os.ttyname(slave)
    vehicle = Vehicle()

    async def main() -> None:
        link = connect(f"serial://{dev}:57600")
        try:
            opening = asyncio.create_task(link.open(timeout=5.0))
            while not opening.done():
                os.write(master, vehicle.heartbeat())
                await asyncio.sleep(0.05)
            await opening
            assert await _receive_two(link, lambda: os.write(master, vehicle.two_positions())) == [100, 200]
            with link.subscribe("LOCAL_POSITION_NED") as sub:
                t0 = time.monotonic()
                os.close(master)
                with pytest.raises(LinkLost, match=dev):
                    await sub.next(5.0)
                assert time.monotonic() - t0 < 1.0
            with pytest.raises(LinkLost):
                await link.recv("HEARTBEAT", 5.0)
            t0 = time.monotonic()
            with pytest.raises(LinkLost):
                await link.arm()
            assert time.monotonic() - t0 < 0.5  # not three 1 s retries
            link.send_heartbeat()  # sending on a lost link drops the frame, never raises
        finally:
            link.close()
        for t in _serial_threads(dev):
            t.join(2.0)
            assert not t.is_alive(), t.name

    try:
        asyncio.run(main())
    finally:
        os.close(slave)
    lost = [r for r in caplog.records if r.name == "plmarl.mavlink"]
    assert len(lost) == 1 and lost[0].levelno == logging.ERROR
    # pyserial's words for a hung-up line (here: "device reports readiness to read but returned no data")
    assert re.fullmatch(f"serial port {dev}: .+; link closed", lost[0].getMessage())
