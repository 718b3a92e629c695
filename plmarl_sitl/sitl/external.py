"""Vehicles that fly elsewhere, as the SITL world sees them: one MAVLink link of its own each.

Real autopilots (the ArduCopter SITL processes `plmarl swarm up --autopilot arducopter=PATH`
starts, or real drones behind a MAVLink router: `plmarl world --external URL,...`) fly
under their agents on links of their own. The world opens a second link to each vehicle
(ArduPilot SITL: SERIAL1) and takes from it what the emulator gives it in-process:

* positions in the mission frame: LOCAL_POSITION_NED (asked for at 10 Hz on this link),
  placed by HOME_POSITION with the agent's own code (`mavlink.vehicle_view.place_home`);
* the armed flag and the mode, from the autopilot's HEARTBEAT (`mavlink.vehicle_view`);
* the vehicle's clock, time_boot_ms.

Each vehicle has a clock of its own: an ArduPilot SITL starts its clock when its first
client connects and then runs at its own pace (at most --speedup x wall; slower on a busy
machine). The world follows them instead of assuming: `now` is the slowest live vehicle's
boot time moved onto a common reference (vehicle i's clock minus its offset; the offsets
are measured while the vehicles boot and frozen when the mission starts), so the world
never processes a second some vehicle has not reached. The mission start t0 is sent to
each agent on its own vehicle's clock (`start_times`).

A link that cannot be opened, or breaks, is retried for as long as the world runs; what
each vehicle is waiting for is in `not_ready`, which the world logs.

Autopilot faults are PARAM_SETs of ArduPilot SITL's SIM_ parameters on this link
(`sitl.vehicles.GPS_OFF`, ...); the PARAM_VALUE the vehicle echoes is reported
(`fault_reports`), and so is every STATUSTEXT of a vehicle under a fault. A real drone has
no SIM_ parameters: it echoes nothing, which is reported as unconfirmed. A PX4 vehicle (its
heartbeat says so) gets PX4's own failure injection instead (`sitl.px4.inject_fault`).
"""

from __future__ import annotations

import asyncio
import logging
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO

import torch

from plmarl_sitl.deploy.mavlink.client import VehicleLink
from plmarl_sitl.deploy.mavlink.connect import connect, parse_url
from plmarl_sitl.deploy.mavlink.vehicle_view import HOME_POSITION_ID, LOCAL_POSITION_NED_ID, VehicleView, place_home
from plmarl_sitl.errors import LinkLost, UserError, VehicleTimeout, VehicleUnreachable
from plmarl_sitl.mission import Mission
from plmarl_sitl.sitl.vehicles import GPS_OFF, GPS_ON, MOTOR_FAIL

log = logging.getLogger("plmarl.world")

WORLD_SYSID = 254  # the world's MAVLink system id on its links (agents are 255)
TELEMETRY_HZ = 10.0  # LOCAL_POSITION_NED on the world's link, vehicle time
OPEN_TIMEOUT_S = 10.0  # wall: one attempt to open a link (then it is tried again)
ASK_EVERY_S = 2.0  # wall: ask for the home position / the stream again until they come
SILENT_S = 5.0  # wall: a vehicle not heard this long has no known position (not counted)
CLIMB_DONE_MPS = 0.5  # |vertical speed| under this at take-off altitude: the climb is over
STREAM_GAP_S = 1.0  # vehicle s: no LOCAL_POSITION_NED this long (10 Hz asked for): its EKF has no position
PARAM_TRIES = 3  # PARAM_SET attempts (2 s each) before a fault is reported unconfirmed


@dataclass
class ExternalVehicle:
    """What the world knows of one vehicle, from its link."""

    index: int
    url: str
    rate: float  # vehicle seconds per wall second (the expected speedup until measured)
    link: VehicleLink | None = None
    state: str = "not connected yet"  # what it is waiting for, until it streams its position
    mode: str = "?"
    offboard_mode: str = "?"  # the personality's (PX4 OFFBOARD, ArduPilot GUIDED)
    autopilot: str = "?"  # the personality's name, from its heartbeat (px4, ardupilot)
    armed: bool = False
    killed: bool = False
    origin: tuple[float, float, float] | None = None  # its local frame's origin in the mission frame
    local: tuple[float, ...] | None = None  # the latest LOCAL_POSITION_NED: x, y, z, vx, vy, vz
    boot_s: float | None = None  # time_boot_ms of that sample, s
    wall_s: float = -math.inf  # perf_counter when it arrived
    tlog: BinaryIO | None = None
    faulted: bool = False  # under an autopilot fault: its STATUSTEXTs are reported
    _rate_ref: tuple[float, float] | None = field(default=None, repr=False)  # (wall, boot) the rate is measured from

    def observe(self, boot_s: float, wall_s: float) -> None:
        """A sample of the vehicle's clock; its rate is re-measured every wall second, smoothed."""
        self.boot_s, self.wall_s = boot_s, wall_s
        if self._rate_ref is None or boot_s < self._rate_ref[1]:  # first sample, or the vehicle rebooted
            self._rate_ref = (wall_s, boot_s)
            return
        w0, b0 = self._rate_ref
        if wall_s - w0 >= 1.0:
            self.rate = 0.5 * self.rate + 0.5 * (boot_s - b0) / (wall_s - w0)
            self._rate_ref = (wall_s, boot_s)

    def clock_at(self, wall_s: float) -> float:
        """Its boot clock at wall time `wall_s`, extrapolated from the latest sample."""
        assert self.boot_s is not None
        return self.boot_s + self.rate * (wall_s - self.wall_s)

    def flying_data(self) -> bool:
        return self.origin is not None and self.local is not None

    def heard(self, wall_s: float) -> bool:
        return self.boot_s is not None and wall_s - self.wall_s < SILENT_S

    def position(self) -> tuple[float, float, float]:
        assert self.origin is not None and self.local is not None
        return (self.origin[0] + self.local[0], self.origin[1] + self.local[1], self.origin[2] + self.local[2])


class ExternalVehicles:
    """`WorldVehicles` for autopilots that run elsewhere, one MAVLink URL each (the
    `mavlink.connect` syntax: tcpout://HOST:PORT, udpin://BIND:PORT, udpout://HOST:PORT)."""

    owns_clock = False

    def __init__(self, mission: Mission, urls: list[str], speedup: float = 1.0,
                 signing_keys: list[bytes] | None = None) -> None:
        if len(urls) != mission.n_uavs:
            raise UserError(f"{len(urls)} vehicle URL(s) for a mission of {mission.n_uavs} UAVs: give one per UAV")
        if signing_keys is not None and len(signing_keys) != len(urls):
            raise UserError(f"{len(signing_keys)} MAVLink signing key(s) for {len(urls)} vehicles")
        self.signing_keys = signing_keys  # vehicle i's MAVLink signing key (None: unsigned links)
        for url in urls:
            parse_url(url)  # a malformed URL is a UserError now, not a retry loop later
        self.mission = mission
        self.vehicles = [ExternalVehicle(i, url, float(speedup)) for i, url in enumerate(urls)]
        self.offsets = [0.0] * len(urls)  # vehicle i's clock minus the reference clock
        self.frozen = False  # offsets fixed (the mission has started)
        self.changed = asyncio.Event()  # set on every position sample (the world waits on it)
        self._now = -math.inf
        self._tasks: list[asyncio.Task] = []
        self._tlog_dir: Path | None = None
        self._warned_gnss = False
        self._reports: list[dict] = []

    # ------------------------------------------------------------------ lifecycle
    @property
    def n(self) -> int:
        return len(self.vehicles)

    @property
    def urls(self) -> list[str]:
        return [v.url for v in self.vehicles]

    @property
    def started(self) -> bool:
        return bool(self._tasks)

    async def start(self) -> None:
        """Start following every vehicle (links are opened, and reopened, in the background)."""
        for v in self.vehicles:
            self._tasks.append(asyncio.create_task(self._follow(v), name=f"vehicle{v.index}-link"))

    def close(self) -> None:
        for t in self._tasks:
            t.cancel()
        self._tasks.clear()
        for v in self.vehicles:
            if v.link is not None:
                v.link.close()
                v.link = None
            if v.tlog is not None:
                v.tlog.close()
                v.tlog = None

    def record_tlogs(self, directory: Path) -> list[Path]:
        """The world's link to vehicle i, both ways, to DIR/vehicle<i>.tlog."""
        directory.mkdir(parents=True, exist_ok=True)
        paths = []
        for v in self.vehicles:
            paths.append(directory / f"vehicle{v.index}.tlog")
            v.tlog = open(paths[-1], "wb")  # noqa: SIM115 - closed in close()
            if v.link is not None:
                v.link.tlog = v.tlog
        return paths

    # ------------------------------------------------------------------ one vehicle's link
    async def _follow(self, v: ExternalVehicle) -> None:
        """Open the link (again, if it breaks) and follow the vehicle, for ever."""
        while True:
            key = self.signing_keys[v.index] if self.signing_keys is not None else None
            link = connect(v.url, sysid=WORLD_SYSID, signing_key=key)
            link.tlog = v.tlog
            v.state = f"connecting to {v.url}"
            try:
                await link.open(timeout=OPEN_TIMEOUT_S)
            except VehicleUnreachable:  # no heartbeat yet, or the connection closed while opening
                link.close()
                v.state = f"no autopilot heartbeat on {v.url} yet"
                continue
            except (OSError, UserError) as exc:  # udpin address in use, serial port missing: try again
                link.close()
                v.state = f"cannot open {v.url}: {exc}"
                await asyncio.sleep(ASK_EVERY_S)
                continue
            v.link = link
            p = link.personality
            assert p is not None
            v.offboard_mode, v.autopilot = p.offboard_mode, p.name
            log.info("vehicle %d: %s autopilot, sysid %d, on %s", v.index, p.name, link.sysid, v.url)
            try:
                await self._serve(v, link)
            except LinkLost as exc:
                log.warning("vehicle %d: link lost (%s); reconnecting", v.index, exc.reason)
            finally:
                link.close()
                v.link = None

    async def _serve(self, v: ExternalVehicle, link: VehicleLink) -> None:
        view = VehicleView(link)
        mine = view.from_autopilot  # not a GCS's forwarded heartbeat
        streaming = False
        asked = -math.inf
        with (link.subscribe("LOCAL_POSITION_NED", mine) as positions, link.subscribe("HEARTBEAT", mine) as beats,
              link.subscribe("HOME_POSITION", mine) as homes, link.subscribe("STATUSTEXT", mine) as texts):
            v.state = "waiting for its home position (set once its EKF has an origin)"
            while True:
                if (not streaming or v.origin is None) and time.monotonic() - asked >= ASK_EVERY_S:
                    asked = time.monotonic()
                    streaming = streaming or await view.stream(LOCAL_POSITION_NED_ID, TELEMETRY_HZ)
                    if v.origin is None:
                        await view.request(HOME_POSITION_ID)
                try:
                    m = await positions.newest(0.5)
                except VehicleTimeout:
                    m = None
                while beats.queued:
                    state = view.state(beats.queued.popleft())
                    v.mode, v.armed = state.mode, state.armed
                while homes.queued:
                    self.place(v, homes.queued.popleft())
                while texts.queued:
                    text = texts.queued.popleft().text
                    if v.faulted and v.boot_s is not None:
                        self._reports.append({"uav": v.index, "boot_s": round(v.clock_at(time.perf_counter()), 3),
                                              "text": text.rstrip("\x00").strip()})
                if m is None:
                    continue
                v.local = (m.x, m.y, m.z, m.vx, m.vy, m.vz)
                v.observe(m.time_boot_ms / 1000.0, time.perf_counter())
                if v.origin is None:
                    v.state = "streaming its position, but no home position yet"
                self._on_sample()

    def place(self, v: ExternalVehicle, home: Any) -> None:
        """Vehicle v's local frame in the mission frame, from a HOME_POSITION (as the agent's)."""
        o = self.mission.origin
        placed = place_home(o.lat_deg, o.lon_deg, o.alt_m, home)
        first = v.origin is None
        v.origin = placed.origin
        if first:
            log.info("vehicle %d: home %.7f, %.7f, %.1f m: local origin at %s in the mission frame", v.index,
                     placed.lat_deg, placed.lon_deg, placed.alt_m, [round(x, 1) for x in v.origin])

    # ------------------------------------------------------------------ the clock
    def _on_sample(self) -> None:
        if not self.frozen:
            self._estimate_offsets()
        self.changed.set()

    def _estimate_offsets(self) -> None:
        """Each heard vehicle's clock minus the lowest-numbered heard one's, at one wall instant."""
        w = time.perf_counter()
        heard = [v for v in self.vehicles if v.boot_s is not None]
        if not heard:
            return
        ref = heard[0].clock_at(w)
        for v in heard:
            self.offsets[v.index] = v.clock_at(w) - ref

    @property
    def now(self) -> float:
        """The slowest live vehicle's latest boot time on the reference clock (never
        backwards); -inf until a vehicle is heard."""
        w = time.perf_counter()
        live = [v.boot_s - self.offsets[v.index] for v in self.vehicles
                if not v.killed and v.heard(w) and v.boot_s is not None]
        if live:
            self._now = max(self._now, min(live))
        return self._now

    def start_times(self, t0: float) -> list[float]:
        """t0 (reference clock) on each vehicle's clock, whole ms; the offsets are fixed from now on."""
        self._estimate_offsets()
        self.frozen = True
        log.info("vehicle clock offsets at the start: %s s; rates %s", [round(x, 3) for x in self.offsets],
                 [round(v.rate, 2) for v in self.vehicles])
        return [round(t0 + off, 3) for off in self.offsets]

    def advance(self, dt_s: float) -> None:
        raise RuntimeError("external vehicles keep their own clocks")

    # ------------------------------------------------------------------ state
    def positions(self) -> torch.Tensor:
        out = torch.zeros(self.n, 3, dtype=torch.float64)
        for v in self.vehicles:
            if v.flying_data():
                out[v.index] = torch.tensor(v.position(), dtype=torch.float64)
        return out

    def alive(self) -> torch.Tensor:
        """Not failed, heard lately and placed: a vehicle whose position is unknown covers nothing."""
        w = time.perf_counter()
        return torch.tensor([not v.killed and v.heard(w) and v.flying_data() for v in self.vehicles])

    def kill(self, i: int) -> None:
        """Node failure: the world counts vehicle i as failed (no coverage, no relaying); the
        launcher kills its agent. The vehicle itself is not touched: it flies on under its
        autopilot's own failsafe (ArduPilot GUIDED: brake after GUID_TIMEOUT)."""
        self.vehicles[i].killed = True

    def set_gnss_noise(self, i: int, std_m: float) -> None:
        if not self._warned_gnss:
            self._warned_gnss = True
            log.warning("gnss_noise: external autopilots navigate on their own GNSS; the event is not applied")

    # ------------------------------------------------------------------ autopilot faults
    def set_gps(self, i: int, on: bool) -> None:
        if self.vehicles[i].autopilot == "px4":
            self._inject(i, "gps", on)
        else:
            self._set_params(i, GPS_ON if on else GPS_OFF)

    def fail_motor(self, i: int) -> None:
        if self.vehicles[i].autopilot == "px4":
            self._inject(i, "motor", False)
        else:
            self._set_params(i, MOTOR_FAIL)

    def _inject(self, i: int, unit: str, ok: bool) -> None:
        """PX4's own failure injection on the world's link (`sitl.px4.inject_fault`), reported."""
        from plmarl_sitl.sitl.px4 import inject_fault

        v = self.vehicles[i]
        v.faulted = True

        async def run() -> None:
            while v.link is None:
                await asyncio.sleep(ASK_EVERY_S)
            report = await inject_fault(v.link, unit, ok)
            self._reports.append({"uav": v.index, "boot_s": round(v.clock_at(time.perf_counter()), 3), **report,
                                  "via": f"{report['via']} on {v.url}"})
            if "error" in report:
                log.warning("vehicle %d: %s fault injection not confirmed: %s", i, unit, report["error"])

        self._tasks.append(asyncio.get_running_loop().create_task(run(), name=f"vehicle{i}-fault"))

    def mark_failed(self, i: int) -> None:
        self.kill(i)

    def _set_params(self, i: int, params: tuple[tuple[str, float], ...]) -> None:
        v = self.vehicles[i]
        v.faulted = True
        self._tasks.append(asyncio.get_running_loop().create_task(self._param_set(v, params), name=f"vehicle{i}-fault"))

    async def _param_set(self, v: ExternalVehicle, params: tuple[tuple[str, float], ...]) -> None:
        """PARAM_SET each parameter on the world's link; report the echo (or that none came)."""
        for name, value in params:
            why = "no link"
            for _ in range(PARAM_TRIES):
                link = v.link
                if link is None:
                    await asyncio.sleep(ASK_EVERY_S)
                    continue
                try:
                    echo = await link.param_set(name, value)
                except VehicleUnreachable as exc:
                    why = str(exc)
                    continue
                self._reports.append({"uav": v.index, "boot_s": round(v.clock_at(time.perf_counter()), 3), "param": name,
                                      "set": value, "echo": echo, "via": f"PARAM_SET on {v.url}"})
                if echo != value:
                    log.warning("vehicle %d: %s set to %g, but it reports %g", v.index, name, value, echo)
                break
            else:
                log.warning("vehicle %d: %s %g not confirmed (%s): not an ArduPilot SITL?", v.index, name, value, why)
                self._reports.append({"uav": v.index, "boot_s": v.boot_s, "param": name, "set": value, "echo": None,
                                      "via": f"PARAM_SET on {v.url}", "error": why})

    def fault_reports(self) -> list[dict]:
        out, self._reports = self._reports, []
        return out

    def position_streams(self, i: int) -> bool:
        v = self.vehicles[i]
        return v.boot_s is not None and v.clock_at(time.perf_counter()) - v.boot_s < STREAM_GAP_S

    def uav_rows(self) -> list[dict]:
        w = time.perf_counter()
        rows = []
        for v in self.vehicles:
            row: dict = {"id": v.index, "mode": v.mode, "armed": v.armed, "alive": not v.killed and v.heard(w), "acc": None}
            if v.flying_data():
                assert v.local is not None
                p = v.position()
                row.update(pos=[round(x, 2) for x in p], vel=[round(x, 3) for x in v.local[3:]], alt=round(-p[2], 2))
            target = v.link.latest.get("POSITION_TARGET_LOCAL_NED") if v.link is not None else None
            if target is not None:
                row["acc"] = [round(target.afx, 2), round(target.afy, 2), round(target.afz, 2)]
            rows.append(row)
        return rows

    def not_ready(self, takeoff_alt_m: float) -> list[str]:
        out = []
        for v in self.vehicles:
            if v.killed:
                continue
            if not v.flying_data():
                out.append(f"{v.index} ({v.state})")
                continue
            assert v.local is not None
            alt, climbing = -v.position()[2], abs(v.local[5]) >= CLIMB_DONE_MPS
            if not (v.armed and v.mode == v.offboard_mode) or alt < takeoff_alt_m - 1.0 or climbing:
                out.append(f"{v.index} ({v.mode}, {'armed' if v.armed else 'disarmed'}, {alt:.1f} m"
                           f"{', climbing' if climbing else ''})")
        return out

    def describe(self) -> str:
        return ", ".join(f"{v.index}: {v.url}" for v in self.vehicles)

