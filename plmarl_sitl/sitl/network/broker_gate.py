"""A TCP relay in front of the MQTT broker, so a mission can take the broker away.

Every client of a launched swarm (world and agents) connects through the gate. An outage
closes every relayed connection and stops listening until it ends, so a new connection is
refused by the kernel: from the clients' side exactly a broker that stopped and restarted.
(Accepting and closing at once is not the same: aiomqtt ignores a hang-up that comes before
the CONNACK and waits out its whole connect timeout, which outlasted short outages.) It
works the same for the embedded broker and for an external one the launcher cannot restart.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import socket

log = logging.getLogger("plmarl.gate")


class BrokerGate:
    def __init__(self, upstream_host: str, upstream_port: int, host: str = "127.0.0.1", port: int = 0) -> None:
        self.upstream = (upstream_host, upstream_port)
        self.host, self.port = host, port
        self.down = False
        self._server: asyncio.Server | None = None
        self._restart: asyncio.Task | None = None  # the task that serves again after an outage
        self._writers: set[asyncio.StreamWriter] = set()

    @property
    def url(self) -> str:
        return f"mqtt://{self.host}:{self.port}"

    async def start(self) -> None:
        await self._serve(self._listen())

    async def close(self) -> None:
        self._drop_all()
        if self._server is not None:
            self._server.close()
            with contextlib.suppress(Exception):
                async with asyncio.timeout(2):
                    await self._server.wait_closed()

    def outage(self, on: bool) -> None:
        """Start (drop everything, stop listening) or end an outage (listen again on the same
        port). Called from the event loop's thread."""
        if on and not self.down:
            assert self._server is not None
            self._server.close()  # closes the listening socket now: new connections are refused
            self._drop_all()
        elif self.down and not on:
            # The socket listens (and queues connections) from here; accepting starts with the task.
            self._restart = asyncio.get_running_loop().create_task(self._serve(self._listen()))
        self.down = on
        log.warning("broker %s", "unreachable (outage)" if on else "back")

    def _listen(self) -> socket.socket:
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # the same port again after an outage
        sock.bind((self.host, self.port))
        sock.listen(128)
        self.port = sock.getsockname()[1]
        return sock

    async def _serve(self, sock: socket.socket) -> None:
        self._server = await asyncio.start_server(self._client, sock=sock)

    def _drop_all(self) -> None:
        for w in list(self._writers):
            w.close()
        self._writers.clear()

    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            up_reader, up_writer = await asyncio.open_connection(*self.upstream)
        except OSError:
            writer.close()
            return
        self._writers.update((writer, up_writer))
        try:
            async with asyncio.TaskGroup() as tg:
                tg.create_task(self._pipe(reader, up_writer))
                tg.create_task(self._pipe(up_reader, writer))
        except* (ConnectionError, OSError):
            pass
        finally:
            for w in (writer, up_writer):
                self._writers.discard(w)
                w.close()

    @staticmethod
    async def _pipe(src: asyncio.StreamReader, dst: asyncio.StreamWriter) -> None:
        try:
            while data := await src.read(65536):
                dst.write(data)
                await dst.drain()
        finally:
            dst.close()
