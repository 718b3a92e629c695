"""MAVLink links over real transports: subscriptions keep every parsed message, and a
serial port that goes away ends the link (logged once) instead of a silent busy loop,
and a flying agent whose radio is unplugged exits at once, non-zero, without a traceback.

The vehicle side is a pymavlink encoder writing frames by hand into a UDP socket, a TCP
connection or the master end of a pseudo-terminal (the link opens the slave end as its
serial port), so two frames can be put in one datagram or one write on purpose.
"""

from __future__ import annotations

import asyncio
import dataclasses
import logging
import os
import re
import shutil
import socket
import sys
import threading
import time
import tty
from pathlib import Path

import pytest

from plmarl_sitl.deploy.agent.config import AgentConfig
from plmarl_sitl.deploy.agent.core import Agent
from plmarl_sitl.deploy.mavlink.codec import Codec, dialect
from plmarl_sitl.deploy.mavlink.connect import connect
from plmarl_sitl.errors import LinkLost, VehicleTimeout
from plmarl_sitl.learning.nn.io import load_policy
from plmarl_sitl.mission import load_mission
from plmarl_sitl.sitl.autopilot.host import AutopilotHost
from plmarl_sitl.sitl.network.broker import MosquittoBroker, free_port, free_udp_ports

from .conftest import MISSION, ROOT
from .test_agent import RecordingBus

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


class RadioBridge:
    """A telemetry radio: the pty's master end <-> the emulated vehicle's UDP port, whole
    MAVLink 2 frames per datagram. `unplug()` closes the master, as pulling the USB radio."""

    def __init__(self, vehicle_port: int) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        self.dev = os.ttyname(self.slave)
        self.vehicle_port = vehicle_port
        self.pending = b""

    async def start(self) -> None:
        loop = asyncio.get_running_loop()
        bridge = self

        class Down(asyncio.DatagramProtocol):
            def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
                if bridge.master >= 0:
                    os.write(bridge.master, data)

        self.udp, _ = await loop.create_datagram_endpoint(Down, remote_addr=("127.0.0.1", self.vehicle_port))
        loop.add_reader(self.master, self._up)

    def _up(self) -> None:
        self.pending += os.read(self.master, 4096)
        while len(self.pending) >= 12 and len(self.pending) >= 12 + self.pending[1]:  # unsigned MAVLink 2
            n = 12 + self.pending[1]
            self.udp.sendto(self.pending[:n])
            self.pending = self.pending[n:]

    def unplug(self) -> None:
        asyncio.get_running_loop().remove_reader(self.master)
        os.close(self.master)
        self.master = -1

    def close(self) -> None:
        if self.master >= 0:
            self.unplug()
        self.udp.close()
        os.close(self.slave)


@pytest.mark.integration
@pytest.mark.slow
@pytest.mark.timeout(180)
@pytest.mark.skipif(not shutil.which("mosquitto") and not os.path.exists("/usr/sbin/mosquitto"),
                    reason="mosquitto not installed")
def test_the_agent_stops_with_one_line_when_its_radio_is_unplugged(policy_dir: Path) -> None:
    """A flying agent on a serial radio: the radio goes, the agent exits non-zero at once
    with the link's line and its own, no traceback."""
    pytest.importorskip("serial")

    async def main() -> tuple[int | None, str, float, str]:
        base = free_udp_ports(1)
        host = AutopilotHost(1, base_port=base)
        await host.start()

        async def clock() -> None:  # about 2x real time
            while True:
                host.advance(0.02)
                await asyncio.sleep(0.01)

        ticking = asyncio.create_task(clock())
        radio = RadioBridge(base)
        await radio.start()
        with MosquittoBroker() as broker:
            agent = await asyncio.create_subprocess_exec(
                sys.executable, "-m", "plmarl_sitl.cli", "agent", "--id", "0", "--connect", f"serial://{radio.dev}:57600",
                "--broker", broker.url, "--bus", "direct", "--start", "now", "--mission", str(MISSION),
                "--policy", str(policy_dir), "-v", "--no-auth", cwd=ROOT, stderr=asyncio.subprocess.PIPE,
            )
            assert agent.stderr is not None
            err: list[str] = []
            try:
                async with asyncio.timeout(150):
                    while "mission clock" not in (line := (await agent.stderr.readline()).decode()):
                        assert line, "".join(err)  # the agent ended before flying
                        err.append(line)
                t0 = time.monotonic()
                radio.unplug()
                async with asyncio.timeout(10):
                    rest = await agent.stderr.read()
                    await agent.wait()
                took = time.monotonic() - t0
            finally:
                if agent.returncode is None:
                    agent.kill()
                    await agent.wait()
                radio.close()
                ticking.cancel()
                host.close()
        return agent.returncode, rest.decode(), took, radio.dev

    code, err, took, dev = asyncio.run(main())
    assert code not in (0, None), err
    assert "Traceback" not in err, err
    assert took < 5.0  # not a 5 s telemetry timeout: the link ended at once
    link_lines = [x for x in err.splitlines() if "link closed" in x]
    assert len(link_lines) == 1 and f"serial port {dev}: " in link_lines[0], err
    assert any("vehicle lost" in x and "link lost" in x for x in err.splitlines()), err


def test_the_agents_heartbeat_waits_for_a_tcp_autopilot_that_is_slow_to_accept(policy_dir: Path) -> None:
    """ArduPilot SITL's SERIAL0 can take seconds to accept a connection while it is busy (a
    loaded machine, the launcher's key provisioning just closed): the agent's 1 Hz GCS
    heartbeat must wait for the link, not end the agent with "link not open" (a real
    two-ArduCopter mission did, session 13). Nobody listens here for 1.5 s, then the
    autopilot accepts and speaks: the agent finds it."""
    mission = dataclasses.replace(load_mission(MISSION), n_uavs=1)

    async def main() -> tuple[bool, bool, int]:
        port = free_port()
        url = f"tcpout://127.0.0.1:{port}"
        link = connect(url)
        assert not link.is_open
        session = Agent(AgentConfig(uav_id=0, connect_url=url, mission=mission), load_policy(policy_dir, mission),
                        RecordingBus(), link).session
        finding = asyncio.create_task(session._find_autopilot())
        session.started = True  # as start() says before it looks for the autopilot
        beating = asyncio.create_task(session.gcs_heartbeat())
        await asyncio.sleep(1.5)  # a tick or two of the heartbeat while nothing accepts
        heartbeat_alive = not beating.done()
        vehicle = Vehicle()

        async def serve(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            writer.write(vehicle.heartbeat())
            await reader.read(1)  # the agent's hello

        server = await asyncio.start_server(serve, "127.0.0.1", port)
        try:
            personality = await asyncio.wait_for(finding, 10.0)
            await asyncio.sleep(1.2)  # a heartbeat tick on the open link
            return heartbeat_alive, not beating.done(), personality.name == "px4" and link.sent
        finally:
            beating.cancel()
            link.close()
            server.close()

    heartbeat_alive, still_beating, sent = asyncio.run(main())
    assert heartbeat_alive, "the GCS heartbeat ended while the TCP connection was still being made"
    assert still_beating and sent
