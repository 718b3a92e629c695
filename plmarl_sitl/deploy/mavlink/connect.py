"""`connect(url)`: a `VehicleLink` for a MAVSDK-style connection URL.

| URL | transport |
|---|---|
| `udpout://HOST:PORT` (also `udp://` without a bind address) | we send first to HOST:PORT (PX4 SITL's offboard port, the emulator) |
| `udpin://BIND:PORT` | we listen; the autopilot sends first and we answer the address it used |
| `tcpout://HOST:PORT` | TCP client (ArduPilot SITL serial0 on 5760) |
| `serial:///dev/ttyACM0:57600` | serial port (a thread reads, so the event loop never blocks) |

Datagram links parse one datagram at a time; stream links (tcp, serial) keep the parser
state across reads, since frames span chunks there.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import queue
import threading
from dataclasses import dataclass
from urllib.parse import urlsplit

from plmarl_sitl.deploy.mavlink.client import VehicleLink, _Protocol
from plmarl_sitl.deploy.mavlink.codec import dialect
from plmarl_sitl.errors import UserError

log = logging.getLogger("plmarl.mavlink")


@dataclass(frozen=True)
class Endpoint:
    scheme: str  # udpout | udpin | tcpout | serial
    host: str  # host, bind address, or device path
    port: int  # port or baud rate


def parse_url(url: str) -> Endpoint:
    parts = urlsplit(url)
    scheme = parts.scheme
    if scheme == "serial":
        path = (parts.netloc + parts.path) or ""
        dev, _, baud = path.rpartition(":")
        if not dev or not baud.isdigit():
            raise UserError(f"connection URL {url!r}: expected serial:///dev/DEVICE:BAUD")
        return Endpoint("serial", dev, int(baud))
    if scheme not in ("udp", "udpout", "udpin", "tcp", "tcpout"):
        raise UserError(f"connection URL {url!r}: scheme must be udpout, udpin, tcpout or serial")
    try:
        port = parts.port
    except ValueError as exc:
        raise UserError(f"connection URL {url!r}: bad port") from exc
    if port is None or not parts.hostname:
        raise UserError(f"connection URL {url!r}: expected {scheme}://HOST:PORT")
    scheme = {"udp": "udpout", "tcp": "tcpout"}.get(scheme, scheme)
    return Endpoint(scheme, parts.hostname, port)


def connect(url: str, **kwargs: object) -> VehicleLink:
    """An unopened link for `url` (kwargs as for VehicleLink); `await link.open()` next."""
    ep = parse_url(url)
    cls = {"udpout": VehicleLink, "udpin": UdpInLink, "tcpout": TcpLink, "serial": SerialLink}[ep.scheme]
    return cls(ep.host, ep.port, **kwargs)  # type: ignore[arg-type]


class _InProtocol(_Protocol):
    link: UdpInLink

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        self.link.peer = addr  # answer whoever spoke last, as MAVSDK's udpin does
        super().datagram_received(data, addr)


class UdpInLink(VehicleLink):
    """Listen on BIND:PORT; replies go to the address the vehicle sent from."""

    peer: tuple[str, int] | None = None  # who spoke last; replies go there

    async def _open_transport(self) -> None:
        loop = asyncio.get_running_loop()
        self._transport, _ = await loop.create_datagram_endpoint(lambda: _InProtocol(self), local_addr=self.addr)

    def _write(self, data: bytes) -> None:
        if self.peer is not None and self._transport is not None:
            self._transport.sendto(data, self.peer)
        # Before the vehicle has spoken there is nobody to answer: the hello is dropped.


class _StreamMixin:
    """Stream decoding: keep the pymavlink parser's buffer between reads."""

    def _on_stream(self: VehicleLink, data: bytes) -> None:  # type: ignore[misc]
        mav = self.codec.mav
        try:
            msgs = mav.parse_buffer(data) or []
        except Exception:  # noqa: BLE001 - pymavlink raises odd errors on hostile bytes
            self.bad_datagrams += 1
            return
        for m in msgs:
            if m.get_msgId() in (dialect.MAVLINK_MSG_ID_BAD_DATA, dialect.MAVLINK_MSG_ID_UNKNOWN):
                self.bad_datagrams += 1
                continue
            self._deliver(m)


class _WriterTransport:
    """Just enough of a transport for VehicleLink (close); writes go through `_write`."""

    def __init__(self, close: object) -> None:
        self._close = close

    def close(self) -> None:
        self._close()  # type: ignore[operator]


class TcpLink(_StreamMixin, VehicleLink):
    """A TCP client (ArduPilot SITL's SERIAL0). Until the autopilot listens, connecting is
    retried (`open` bounds it); once connected, the autopilot closing the connection ends
    the link at once: every wait on it raises LinkLost."""

    _writer: asyncio.StreamWriter | None = None
    RETRY_CONNECT_S = 0.5

    async def _open_transport(self) -> None:
        while True:
            try:
                reader, self._writer = await asyncio.open_connection(*self.addr)
                break
            except OSError as exc:  # refused: not listening yet (a SITL still starting)
                log.debug("tcp %s:%d: %s; retrying", *self.addr, exc)
                await asyncio.sleep(self.RETRY_CONNECT_S)
        self._reader_task = asyncio.create_task(self._read(reader), name=f"mavlink-tcp-{self.addr[1]}")
        self._transport = _WriterTransport(self._close_stream)  # type: ignore[assignment]

    async def _read(self, reader: asyncio.StreamReader) -> None:
        try:
            while data := await reader.read(4096):
                self._on_stream(data)
            reason = "the autopilot closed the connection"
        except ConnectionResetError:  # a close with our unread requests in its buffer is a reset (RST)
            reason = "the autopilot reset the connection"
        except OSError as exc:
            reason = str(exc) or type(exc).__name__
        self._lose(f"tcp {self.addr[0]}:{self.addr[1]}: {reason}")

    def _write(self, data: bytes) -> None:
        if self._writer is not None and not self._writer.is_closing() and self.lost is None:
            self._writer.write(data)  # buffered by asyncio: never blocks

    def _close_stream(self) -> None:
        self._reader_task.cancel()
        if self._writer is not None:
            self._writer.close()


class SerialLink(_StreamMixin, VehicleLink):
    """pyserial in two daemon threads (read, write), so blocking I/O stays off the loop.

    A serial error (the radio unplugged, the port gone) is logged once and ends the link:
    every wait on it raises LinkLost, so the agent stops at once instead of reading a dead
    port in a busy loop."""

    async def _open_transport(self) -> None:
        import serial  # pyserial, imported only when a serial URL is used

        loop = asyncio.get_running_loop()
        dev, baud = self.addr
        try:
            self._serial = await loop.run_in_executor(None, lambda: serial.Serial(dev, baud, timeout=0.1))
        except serial.SerialException as exc:
            raise UserError(f"cannot open serial port {dev}: {exc}") from exc
        self._out: queue.Queue[bytes | None] = queue.Queue(maxsize=256)
        self._running = True

        def failed(exc: Exception) -> None:
            if self._running:  # not our own close()
                loop.call_soon_threadsafe(self._serial_failed, exc)

        def reader() -> None:
            try:
                while self._running:
                    data = self._serial.read(self._serial.in_waiting or 1)
                    if data:
                        loop.call_soon_threadsafe(self._on_stream, data)
            except Exception as exc:  # noqa: BLE001 - pyserial raises SerialException, OSError, TypeError...
                failed(exc)

        def writer() -> None:
            try:
                while (item := self._out.get()) is not None:
                    self._serial.write(item)
            except Exception as exc:  # noqa: BLE001 - as the reader
                failed(exc)

        threading.Thread(target=reader, name=f"serial-read-{dev}", daemon=True).start()
        threading.Thread(target=writer, name=f"serial-write-{dev}", daemon=True).start()
        self._transport = _WriterTransport(self._close_serial)  # type: ignore[assignment]

    def _serial_failed(self, exc: Exception) -> None:
        if self.lost is not None:
            return  # the other thread failed first
        log.error("serial port %s: %s; link closed", self.addr[0], exc)
        self._lose(f"serial port {self.addr[0]}: {exc}")
        self._close_serial()

    def _write(self, data: bytes) -> None:
        with contextlib.suppress(queue.Full):  # a full queue drops the frame (a slow radio, or a lost link)
            self._out.put_nowait(data)

    def _close_serial(self) -> None:
        self._running = False
        with contextlib.suppress(queue.Full):
            self._out.put_nowait(None)
        with contextlib.suppress(Exception):  # closing a port that is already gone
            self._serial.close()
