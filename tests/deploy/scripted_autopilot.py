"""A scripted MAVLink autopilot on a real TCP or UDP socket, for the client behaviours the
emulator cannot show: one that sets its home and starts its position stream late (as a
real EKF does), or never; one that hangs up; one that records the exact COMMAND_LONG
params a client sends. It sends ArduPilot heartbeats, acknowledges every command with
`result`, and (over TCP) HOME_POSITION / LOCAL_POSITION_NED once their time has come."""

from __future__ import annotations

import asyncio
import contextlib
import time

from plmarl_sitl.deploy.mavlink.codec import Codec, dialect

d = dialect


class ScriptedAutopilot:
    def __init__(self, result: int = d.MAV_RESULT_ACCEPTED, home: tuple[float, float, float] | None = None,
                 home_after_s: float = 0.0, position_after_s: float | None = None) -> None:
        self.codec = Codec(1, d.MAV_COMP_ID_AUTOPILOT1, None, allow_unsigned=())
        self.result = result
        self.home = home  # (lat, lon, alt) answered to REQUEST_MESSAGE(HOME_POSITION); None: never set
        self.home_after_s = home_after_s  # after the client connected
        self.position_after_s = position_after_s  # LOCAL_POSITION_NED streams from then on (None: never)
        self.t_connected = 0.0
        self.commands: list[tuple[int, tuple[float, ...]]] = []  # (command, its 7 params), in order
        self.port = 0
        self._writers: list[asyncio.StreamWriter] = []
        self._tasks: list[asyncio.Task] = []
        self._server: asyncio.Server | None = None
        self._udp: asyncio.DatagramTransport | None = None
        self.addr: tuple[str, int] | None = None  # UDP: the client's address, once it has sent

    def heartbeat(self) -> bytes:
        return self.codec.encode(self.codec.mav.heartbeat_encode(
            d.MAV_TYPE_QUADROTOR, d.MAV_AUTOPILOT_ARDUPILOTMEGA, d.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 0,
            d.MAV_STATE_STANDBY))

    def since_connected(self) -> float:
        return time.monotonic() - self.t_connected

    def answers(self, data: bytes, mav) -> list[bytes]:  # noqa: ANN001 - pymavlink's parser
        out = []
        for m in mav.parse_buffer(data) or []:
            if m.get_type() == "COMMAND_LONG":
                params = (m.param1, m.param2, m.param3, m.param4, m.param5, m.param6, m.param7)
                self.commands.append((m.command, params))
                out.append(self.codec.encode(self.codec.mav.command_ack_encode(m.command, self.result, 0, 0, 255, 190)))
                asks_home = m.command == d.MAV_CMD_REQUEST_MESSAGE and m.param1 == d.MAVLINK_MSG_ID_HOME_POSITION
                if asks_home and self.home is not None and self.since_connected() >= self.home_after_s:
                    lat, lon, alt = self.home
                    out.append(self.codec.encode(self.codec.mav.home_position_encode(
                        int(lat * 1e7), int(lon * 1e7), int(alt * 1000), 0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0],
                        0.0, 0.0, 0.0, 0)))
        return out

    # ------------------------------------------------------------------ TCP (ArduPilot SITL's SERIAL0)
    async def serve_tcp(self) -> int:
        self._server = await asyncio.start_server(self._client, "127.0.0.1", 0)
        self.port = self._server.sockets[0].getsockname()[1]
        return self.port

    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        self._writers.append(writer)
        self.t_connected = time.monotonic()
        mav = Codec(1, 1, None, allow_unsigned=()).mav
        beat = asyncio.create_task(self._beat(writer))
        self._tasks.append(beat)
        with contextlib.suppress(ConnectionError):
            while data := await reader.read(4096):
                for frame in self.answers(data, mav):
                    writer.write(frame)
        beat.cancel()

    async def _beat(self, writer: asyncio.StreamWriter) -> None:
        while not writer.is_closing():
            writer.write(self.heartbeat())
            t = self.since_connected()
            if self.position_after_s is not None and t >= self.position_after_s:
                writer.write(self.codec.encode(self.codec.mav.local_position_ned_encode(int(t * 1000), 0, 0, 0, 0, 0, 0)))
            await asyncio.sleep(0.2)

    def hang_up(self) -> None:
        """Close every client connection (the autopilot process ended)."""
        for w in self._writers:
            w.close()

    # ------------------------------------------------------------------ UDP (the emulator's transport)
    async def serve_udp(self) -> int:
        ap = self
        mav = Codec(1, 1, None, allow_unsigned=()).mav

        class Proto(asyncio.DatagramProtocol):
            def connection_made(self, transport: asyncio.BaseTransport) -> None:
                self.transport = transport

            def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
                ap.addr = addr  # the client's, for what a subclass sends unasked
                self.transport.sendto(ap.heartbeat(), addr)  # type: ignore[attr-defined]
                for frame in ap.answers(data, mav):
                    self.transport.sendto(frame, addr)  # type: ignore[attr-defined]

        self._udp, _ = await asyncio.get_running_loop().create_datagram_endpoint(Proto, local_addr=("127.0.0.1", 0))
        self.port = self._udp.get_extra_info("sockname")[1]
        return self.port

    def close(self) -> None:
        self.hang_up()
        for t in self._tasks:
            t.cancel()
        if self._server is not None:
            self._server.close()
        if self._udp is not None:
            self._udp.close()
