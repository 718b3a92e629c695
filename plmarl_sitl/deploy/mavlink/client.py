"""Asyncio MAVLink client for one vehicle: typed helpers instead of raw 7-parameter calls.

Used by the agent (deploy side) and the autopilot benchmark's load generator. One UDP
socket per vehicle, connected like `udpout:` (we speak first, the vehicle answers the
address it saw), so several vehicles never share a link and nothing can latch onto "the
first heartbeat" of the wrong one. Every wait is bounded (`asyncio.timeout`) and a refused
command raises `CommandRejected` with the MAV_RESULT.
"""

from __future__ import annotations

import asyncio
import fcntl
import math
import struct
import time
from collections import Counter, deque
from collections.abc import Callable
from typing import BinaryIO

from plmarl_sitl.deploy.mavlink.codec import Codec, Fields, Message, dialect, enum_name, param_id_str
from plmarl_sitl.deploy.mavlink.personality import Personality, personality_for_autopilot
from plmarl_sitl.deploy.mavlink.wire import ACCEL_ONLY, FORCE_ARM_MAGIC, POSITION_ONLY, VELOCITY_ONLY
from plmarl_sitl.errors import CommandRejected, LinkLost, VehicleTimeout

d = dialect

Predicate = Callable[[Message], bool]


SET_POSITION_TARGET_LOCAL_NED_ID = d.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED
SIOCGSTAMPNS = 0x8907  # Linux: the kernel's receive time of the socket's last datagram


def kernel_rx_ns(fd: int) -> int | None:
    """CLOCK_REALTIME ns at which the kernel received the datagram just read from socket
    `fd` (None where the ioctl is unsupported): the telemetry's arrival, before any time
    the process spent waiting for a CPU."""
    try:
        sec, nsec = struct.unpack("qq", fcntl.ioctl(fd, SIOCGSTAMPNS, bytes(16)))
    except OSError:
        return None
    return sec * 1_000_000_000 + nsec


class _Protocol(asyncio.DatagramProtocol):
    def __init__(self, link: VehicleLink) -> None:
        self.link = link
        self.fd = -1  # the datagram socket, for arrival stamps

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        sock = transport.get_extra_info("socket")
        self.fd = sock.fileno() if sock is not None else -1

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        rx_ns = kernel_rx_ns(self.fd) if self.link.stamp_arrivals and self.fd >= 0 else None
        self.link.feed_datagram(data, rx_ns)

    def error_received(self, exc: Exception) -> None:
        pass  # "port unreachable" while the vehicle is not up yet: keep trying


class Subscription:
    """Every `mtype` message matching `pred` that the link parses from now on, in order.

    Each subscription has its own queue, filled as the link parses: none is missed while
    the subscriber is busy, even the second of two messages parsed from one datagram or
    stream read (a one-shot waiter re-armed after the first would miss it). A subscriber
    more than MAX_QUEUED messages behind loses the oldest (counted in `dropped`). Close it
    when done (or use `with`)."""

    MAX_QUEUED = 1024

    def __init__(self, link: VehicleLink, mtype: str, pred: Predicate | None) -> None:
        self.link = link
        self.mtype = mtype
        self.pred = pred
        self.dropped = 0  # lost for being more than MAX_QUEUED behind
        self.skipped = 0  # passed over by `newest`
        self.queued: deque[Message] = deque()
        self.ended: LinkLost | None = None
        self._waiter: asyncio.Future[None] | None = None  # set while `next` waits
        self._handler: Callable[[Message], None] | None = None  # `handle_with`

    def handle_with(self, handler: Callable[[Message], None] | None) -> None:
        """Hand each matching message to `handler` as the link parses it, in the link's
        receive callback, instead of queueing it (None: queue again). For a loop that must
        answer every message at once (a lockstep agent): no task switch and no timer per
        message. `handler` must not block, and what it raises is the link's (log it, keep
        it): catch inside."""
        self._handler = handler

    def offer(self, m: Message) -> None:
        """Queue `m` if it matches (the link calls this for every parsed `mtype` message),
        or hand it to the handler (`handle_with`)."""
        if self.pred is not None and not self.pred(m):
            return
        if self._handler is not None:
            self._handler(m)
            return
        if len(self.queued) >= self.MAX_QUEUED:
            self.queued.popleft()
            self.dropped += 1
        self.queued.append(m)
        self._wake()

    def end(self, lost: LinkLost) -> None:
        """No more messages will come: a waiting and every later `next` raise `lost`."""
        self.ended = lost
        self._wake()

    def cancel(self) -> None:
        """The link was closed: a waiting `next` is cancelled."""
        if self._waiter is not None:
            self._waiter.cancel()

    def _wake(self) -> None:
        if self._waiter is not None and not self._waiter.done():
            self._waiter.set_result(None)

    async def next(self, timeout: float = 3.0) -> Message:
        """The oldest queued message, waiting up to `timeout` s for one."""
        await self._wait(timeout)
        return self.queued.popleft()

    async def newest(self, timeout: float = 3.0) -> Message:
        """The newest queued message (older ones are dropped, counted in `skipped`), waiting
        up to `timeout` s for one: for a control loop, a state that has been superseded is
        stale, and working through a backlog would only fall further behind."""
        await self._wait(timeout)
        self.skipped += len(self.queued) - 1
        m = self.queued.pop()
        self.queued.clear()
        return m

    async def _wait(self, timeout: float) -> None:
        """Until a message is queued (VehicleTimeout after `timeout` s; the link's LinkLost
        once it ended and nothing is left)."""
        if not self.queued and self.ended is None:
            self._waiter = asyncio.get_running_loop().create_future()
            try:
                async with asyncio.timeout(timeout):
                    await self._waiter
            except TimeoutError:
                raise VehicleTimeout(self.link.target_sysid or 0, self.mtype, timeout) from None
            finally:
                self._waiter = None
        if not self.queued:
            assert self.ended is not None
            raise self.ended

    def close(self) -> None:
        self.link.unsubscribe(self)

    def __enter__(self) -> Subscription:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class VehicleLink:
    """MAVLink 2 link to the vehicle at udp host:port (target sysid learnt or given)."""

    def __init__(
        self,
        host: str,
        port: int,
        *,
        sysid: int = 255,
        compid: int = d.MAV_COMP_ID_MISSIONPLANNER,
        target_sysid: int | None = None,
        signing_key: bytes | None = None,
    ) -> None:
        self.addr = (host, port)
        self.codec = Codec(sysid, compid, signing_key, allow_unsigned=())
        self.target_sysid = target_sysid
        self.personality: Personality | None = None
        self.latest: dict[str, Message] = {}
        self.counts: Counter[str] = Counter()
        self.bad_datagrams = 0
        self.sent = 0
        self._subscriptions: dict[str, list[Subscription]] = {}  # by message type
        self.lost: LinkLost | None = None  # set once the link broke for good
        self._transport: asyncio.DatagramTransport | None = None
        # Stamp each message with its datagram's kernel arrival time (`m.rx_ns`, UDP
        # links only): one ioctl per datagram, for latency measurements.
        self.stamp_arrivals = False
        # How long a COMMAND_LONG waits for its ACK before it is sent again (3 tries). A
        # real autopilot answers in milliseconds; a lockstep SITL world starting 100
        # vehicles on a loaded machine may not run for seconds (`plmarl agent --lockstep`).
        self.command_timeout_s = 1.0
        # Every message received and sent, as a .tlog (8-byte big-endian unix time in us,
        # then the frame: the format pymavlink and MAVExplorer read); None: not recorded.
        self.tlog: BinaryIO | None = None

    # ------------------------------------------------------------------ lifecycle
    async def open(self, timeout: float = 5.0) -> None:
        """Bind (or connect), say hello, and wait for the vehicle's autopilot heartbeat, all
        within `timeout` s (VehicleTimeout otherwise)."""
        t_end = asyncio.get_running_loop().time() + timeout
        try:
            async with asyncio.timeout(timeout):
                await self._open_transport()
        except TimeoutError:
            raise VehicleTimeout(self.target_sysid or 0, "connection to the autopilot", timeout) from None
        timeout = max(0.0, t_end - asyncio.get_running_loop().time())
        want = self.target_sysid

        def is_autopilot(m: Message) -> bool:
            return m.get_srcComponent() == d.MAV_COMP_ID_AUTOPILOT1 and (want is None or m.get_srcSystem() == want)

        async def hello() -> None:
            while True:
                self.send_heartbeat()
                await asyncio.sleep(0.5)

        greeter = asyncio.create_task(hello(), name=f"hello-{self.addr[1]}")
        try:
            hb = await self.recv("HEARTBEAT", timeout, is_autopilot)
        finally:
            greeter.cancel()
        self.target_sysid = hb.get_srcSystem()
        self.personality = personality_for_autopilot(hb.autopilot)

    async def _open_transport(self) -> None:
        """udpout: a connected UDP socket (subclasses in `mavlink.connect` add udpin, tcp, serial)."""
        loop = asyncio.get_running_loop()
        self._transport, _ = await loop.create_datagram_endpoint(lambda: _Protocol(self), remote_addr=self.addr)

    def _write(self, data: bytes) -> None:
        assert self._transport is not None
        self._transport.sendto(data)

    def close(self) -> None:
        if self._transport is not None:
            self._transport.close()
            self._transport = None
        for subs in self._subscriptions.values():
            for sub in subs:
                sub.cancel()
        self._subscriptions.clear()

    async def __aenter__(self) -> VehicleLink:
        await self.open()
        return self

    async def __aexit__(self, *exc: object) -> None:
        self.close()

    @property
    def is_open(self) -> bool:
        """Its transport is up (TCP: connected), so `send` works; `open` may still be
        waiting for the autopilot's heartbeat."""
        return self._transport is not None

    @property
    def sysid(self) -> int:
        if self.target_sysid is None:
            raise RuntimeError("link not open")
        return self.target_sysid

    # ------------------------------------------------------------------ receiving
    def feed_datagram(self, data: bytes, rx_ns: int | None = None) -> None:
        """Parse one datagram (or one stream read) the transport received at `rx_ns`."""
        out = self.codec.decode_datagram(data)
        if out.fault is not None:
            self.bad_datagrams += 1
        for m in out.messages:
            if rx_ns is not None:
                m.rx_ns = rx_ns
            self._deliver(m)

    def _deliver(self, m: Message) -> None:
        """One parsed message: the latest of its type, counted, offered to its subscribers."""
        t = m.get_type()
        if self.tlog is not None:
            self._record(m.get_msgbuf())
        self.latest[t] = m
        self.counts[t] += 1
        for sub in self._subscriptions.get(t, ()):
            sub.offer(m)

    def _lose(self, reason: str) -> None:
        """The transport broke for good: every subscriber's wait ends with LinkLost."""
        if self.lost is not None:
            return
        self.lost = LinkLost(self.target_sysid or 0, reason)
        for subs in self._subscriptions.values():
            for sub in subs:
                sub.end(self.lost)

    def subscribe(self, mtype: str, pred: Predicate | None = None) -> Subscription:
        """Every `mtype` message (matching `pred`) from now on; see `Subscription`."""
        sub = Subscription(self, mtype, pred)
        if self.lost is not None:
            sub.end(self.lost)
        self._subscriptions.setdefault(mtype, []).append(sub)
        return sub

    def unsubscribe(self, sub: Subscription) -> None:
        subs = self._subscriptions.get(sub.mtype, [])
        if sub in subs:
            subs.remove(sub)

    async def recv(self, mtype: str, timeout: float = 3.0, pred: Predicate | None = None) -> Message:
        """The next `mtype` message (matching `pred`) from the vehicle. For a stream of
        messages use `subscribe`: between two `recv` calls a message can pass unseen."""
        with self.subscribe(mtype, pred) as sub:
            return await sub.next(timeout)

    # ------------------------------------------------------------------ sending
    def send(self, msg: Message | Fields) -> None:
        if self._transport is None:
            raise RuntimeError("link not open")
        data = self.codec.encode(msg)
        self._write(data)
        self.sent += 1
        if self.tlog is not None:
            self._record(data)

    def _record(self, frame: bytes) -> None:
        assert self.tlog is not None
        self.tlog.write(struct.pack(">Q", int(time.time() * 1e6)) + frame)

    def send_heartbeat(self) -> None:
        self.send(self.codec.mav.heartbeat_encode(d.MAV_TYPE_GCS, d.MAV_AUTOPILOT_INVALID, 0, 0, d.MAV_STATE_ACTIVE))

    def _setpoint(self, mask: int, pos=(0.0, 0.0, 0.0), vel=(0.0, 0.0, 0.0), acc=(0.0, 0.0, 0.0), time_boot_ms: int = 0) -> None:
        # Sent once per telemetry sample: packed from its fields, no message object (issue 25.1)
        self.send(Fields((SET_POSITION_TARGET_LOCAL_NED_ID, (
            time_boot_ms, self.sysid, d.MAV_COMP_ID_AUTOPILOT1, d.MAV_FRAME_LOCAL_NED, mask, *pos, *vel, *acc, 0.0, 0.0))))

    def send_accel_ned(self, north: float, east: float, down: float, time_boot_ms: int = 0) -> None:
        """Net acceleration setpoint (m/s^2, gravity compensated); (0,0,0) keeps velocity.
        `time_boot_ms`: the vehicle time of the telemetry this setpoint answers (a lockstep
        SITL world waits for it); 0: not stamped."""
        self._setpoint(ACCEL_ONLY, acc=(north, east, down), time_boot_ms=time_boot_ms)

    def send_velocity_ned(self, north: float, east: float, down: float) -> None:
        self._setpoint(VELOCITY_ONLY, vel=(north, east, down))

    def send_position_ned(self, north: float, east: float, down: float) -> None:
        self._setpoint(POSITION_ONLY, pos=(north, east, down))

    # ------------------------------------------------------------------ commands
    async def command(self, command: int, *params: float, timeout: float | None = None, retries: int = 3) -> None:
        """COMMAND_LONG with retries (confirmation counts up); raises unless ACCEPTED.
        `timeout`: per try (None: `command_timeout_s`).

        Params not given are 0, as the MAVLink spec asks for reserved and unused params
        (ArduPilot DENIES e.g. SET_MESSAGE_INTERVAL with NaN in its reserved param 3).
        Pass NaN explicitly only where the command defines NaN ("current yaw/position")."""
        p = list(params) + [0.0] * (7 - len(params))
        if timeout is None:
            timeout = self.command_timeout_s
        with self.subscribe("COMMAND_ACK", lambda m: m.command == command) as acks:
            for attempt in range(retries):
                self.send(self.codec.mav.command_long_encode(self.sysid, d.MAV_COMP_ID_AUTOPILOT1, command, attempt, *p))
                try:
                    ack = await acks.next(timeout)
                except VehicleTimeout:  # unanswered: send again (a lost link, LinkLost, ends here)
                    continue
                if ack.result != d.MAV_RESULT_ACCEPTED:
                    raise CommandRejected(self.sysid, command, ack.result, enum_name("MAV_RESULT", ack.result),
                                          enum_name("MAV_CMD", command))
                return
        raise VehicleTimeout(self.sysid, f"COMMAND_ACK for command {command}", timeout * retries)

    async def arm(self, force: bool = False) -> None:
        await self.command(d.MAV_CMD_COMPONENT_ARM_DISARM, 1.0, float(FORCE_ARM_MAGIC) if force else 0.0)

    async def disarm(self, force: bool = False) -> None:
        await self.command(d.MAV_CMD_COMPONENT_ARM_DISARM, 0.0, float(FORCE_ARM_MAGIC) if force else 0.0)

    async def set_mode(self, name: str) -> None:
        """Mode by name in the vehicle's personality ('OFFBOARD', 'AUTO.LOITER', 'GUIDED', ...)."""
        if self.personality is None:
            raise RuntimeError("link not open")
        p2, p3 = self.personality.set_mode_params(name)
        await self.command(d.MAV_CMD_DO_SET_MODE, float(d.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), p2, p3)

    async def takeoff(self, alt_rel_m: float | None = None, home_amsl_m: float | None = None) -> None:
        """Take off to `alt_rel_m` above home (None: the vehicle's takeoff-altitude parameter).

        PX4 wants param7 as AMSL altitude, so pass `home_amsl_m` with a PX4 vehicle.
        """
        alt = math.nan
        if alt_rel_m is not None:
            if self.personality is not None and self.personality.takeoff_alt_is_amsl:
                if home_amsl_m is None:
                    home = await self.request("HOME_POSITION", d.MAVLINK_MSG_ID_HOME_POSITION)
                    home_amsl_m = home.altitude / 1000.0
                alt = home_amsl_m + alt_rel_m
            else:
                alt = alt_rel_m
        # param4 yaw NaN: keep the current heading; params 5-6 NaN: here (PX4 flies to a
        # given lat/lon; ArduCopter ignores them). Params 1-3 (pitch, empty) are 0.
        await self.command(d.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, alt)

    async def land(self) -> None:
        # Params 1-3 (abort altitude: default; precision mode: off; empty) 0; yaw, lat, lon
        # and ground altitude NaN: keep the heading and land here, on whatever ground is below.
        await self.command(d.MAV_CMD_NAV_LAND, 0, 0, 0, math.nan, math.nan, math.nan, math.nan)

    async def set_message_interval(self, message: str | int, hz: float) -> None:
        """Stream `message` at `hz` (0 stops it)."""
        msgid = message if isinstance(message, int) else getattr(d, f"MAVLINK_MSG_ID_{message.upper()}")
        interval = -1.0 if hz <= 0 else 1e6 / hz
        # Params 3-6 reserved (0: ArduPilot denies anything else in param 3); param 7, the
        # response target, 0: the flight stack's default (the link that asked).
        await self.command(d.MAV_CMD_SET_MESSAGE_INTERVAL, float(msgid), interval, 0, 0, 0, 0, 0)

    async def request_message(self, msgid: int, timeout: float | None = None) -> None:
        """MAV_CMD_REQUEST_MESSAGE: ask for one `msgid` message (raises unless ACCEPTED; an
        autopilot may accept and still send nothing while it has no such data, as ArduPilot
        does for HOME_POSITION before its home is set)."""
        # Params 2-6 (the message's own request params) unused: 0; param 7 response target 0 (default).
        await self.command(d.MAV_CMD_REQUEST_MESSAGE, float(msgid), 0, 0, 0, 0, 0, 0, timeout=timeout)

    async def request(self, mtype: str, msgid: int, timeout: float = 2.0) -> Message:
        """MAV_CMD_REQUEST_MESSAGE and the message it brings (in either order: the
        subscription is made before the command goes out)."""
        with self.subscribe(mtype) as answers:
            await self.request_message(msgid, timeout)
            return await answers.next(timeout)

    # ------------------------------------------------------------------ parameters
    async def param_get(self, name: str, timeout: float = 2.0) -> float:
        """A parameter's wire value (REAL32 as is; integers as their wire float)."""
        with self.subscribe("PARAM_VALUE", lambda m: param_id_str(m.param_id) == name) as values:
            self.send(self.codec.mav.param_request_read_encode(self.sysid, 1, name.encode(), -1))
            return float((await values.next(timeout)).param_value)

    async def param_set(self, name: str, value: float, param_type: int = d.MAV_PARAM_TYPE_REAL32,
                        timeout: float = 2.0) -> float:
        """Set a parameter; returns the value the vehicle reports back (unchanged if refused)."""
        with self.subscribe("PARAM_VALUE", lambda m: param_id_str(m.param_id) == name) as values:
            self.send(self.codec.mav.param_set_encode(self.sysid, 1, name.encode(), value, param_type))
            return float((await values.next(timeout)).param_value)
