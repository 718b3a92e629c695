"""A thin pymavlink client for the suite: commands with their COMMAND_ACK, waits bounded by
vehicle time, and the vehicle clock (time_boot_ms of the last message that carries it)."""

from __future__ import annotations

import time
from collections.abc import Callable

from pymavlink import mavutil

from conformance.targets import Target


class Link:
    def __init__(self, m: mavutil.mavfile, target: Target) -> None:
        self.m = m
        self.mav = mavutil.mavlink
        self.target = target
        self.clock_s = 0.0  # vehicle seconds since boot, from the latest time_boot_ms
        self.texts: list[tuple[float, str]] = []
        self._last_hb_sent = 0.0
        self.sysid = target.sysid

    def close(self) -> None:
        self.m.close()

    def recv(self, timeout: float):
        """The next message from the autopilot (component 1), or None; keeps our heartbeat going."""
        now = time.monotonic()
        if now - self._last_hb_sent > 0.5:
            self._last_hb_sent = now
            self.m.mav.heartbeat_send(self.mav.MAV_TYPE_GCS, self.mav.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        msg = self.m.recv_match(blocking=True, timeout=timeout)
        if (msg is None or msg.get_type() == "BAD_DATA" or msg.get_srcComponent() != 1
                or msg.get_srcSystem() != self.sysid):
            return None
        ms = getattr(msg, "time_boot_ms", None)
        if ms is not None:
            self.clock_s = max(self.clock_s, ms / 1000)
        if msg.get_type() == "STATUSTEXT":
            self.texts.append((self.clock_s, msg.text))
        return msg

    def wait(self, kind: str | list[str], pred: Callable = lambda m: True, sim_s: float = 5.0,
             wall_s: float | None = None):
        """The first message of `kind` meeting `pred` within `sim_s` seconds of the vehicle clock
        (SYSTEM_TIME streams at 10 Hz), or None; a wall-time bound (default: generous for
        `sim_s`) guards against a clock that does not run."""
        kinds = [kind] if isinstance(kind, str) else kind
        until = self.clock_s + sim_s
        deadline = time.monotonic() + (self.target.wall(sim_s) if wall_s is None else wall_s)
        while time.monotonic() < deadline and self.clock_s <= until:
            msg = self.recv(0.1)
            if msg is not None and msg.get_type() in kinds and pred(msg):
                return msg
        return None

    def drain(self) -> None:
        while self.recv(0.0) is not None:
            pass

    def command(self, command: int, *params: float, sim_s: float = 5.0) -> int | None:
        """COMMAND_LONG with the 7 params given; the result of its COMMAND_ACK (None: no ack)."""
        assert len(params) == 7, "give all 7 params: the suite checks what each value does"
        self.m.mav.command_long_send(self.sysid, 1, command, 0, *params)
        ack = self.wait("COMMAND_ACK", lambda a: a.command == command, sim_s=sim_s)
        return None if ack is None else ack.result

    def heartbeat(self):
        return self.wait("HEARTBEAT", sim_s=3.0)
