"""AutopilotHost: N emulated autopilots in one asyncio process, stepped by whoever owns the clock.

The SITL world process owns simulated time: it calls `advance(dt_s)` and every vehicle's
physics, failsafes and telemetry move by exactly that much sim time. The standalone runner
(`runner.run_realtime`) is just one such owner that follows wall time × speedup. Time since
boot (time_boot_ms, SYSTEM_TIME, TIMESYNC) is sim time, so a sped-up run looks like a
normal vehicle to clients that time-stamp by the vehicle clock.

The host owns the sockets, the vehicles and their shared batched state (`Fleet`); each
substep it steps the fleet, runs the state machines that asked to be watched, fires
setpoint-loss failsafes and sends the telemetry that is due.
"""

from __future__ import annotations

import asyncio
import logging
import math
import socket
from collections.abc import Mapping, Sequence
from pathlib import Path

import torch

from plmarl_sitl.config import VehicleModel, load_vehicle
from plmarl_sitl.deploy.mavlink.personality import Personality, personality
from plmarl_sitl.mission import Origin
from plmarl_sitl.model.geodesy import ned_to_geodetic
from plmarl_sitl.model.vehicle import Limits
from plmarl_sitl.sitl.autopilot import handlers, telemetry
from plmarl_sitl.sitl.autopilot.boot import Boot, boot_timeline
from plmarl_sitl.sitl.autopilot.counters import InputCounters
from plmarl_sitl.sitl.autopilot.fleet import Fleet
from plmarl_sitl.sitl.autopilot.guidance import Kind
from plmarl_sitl.sitl.autopilot.schedule import STREAM_PHASES
from plmarl_sitl.sitl.autopilot.vehicle import Vehicle

log = logging.getLogger("plmarl.autopilot")

MAX_SYSID = 250  # PX4's MAV_SYS_ID range; 255 is by convention a ground station


RECEIVE_BUFFER_BYTES = 1 << 20


def _grow_receive_buffer(transport: asyncio.BaseTransport) -> None:
    """Ask for a 1 MiB socket receive buffer (the kernel caps it at net.core.rmem_max).

    The default (~200 KiB, a few hundred small datagrams) overflows when a sped-up run
    gets 400 setpoints/s per vehicle and the loop is busy stepping physics for a few ms.
    """
    sock = transport.get_extra_info("socket")
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECEIVE_BUFFER_BYTES)
    except OSError as exc:
        log.debug("cannot enlarge UDP receive buffer: %s", exc)


class _VehicleProtocol(asyncio.DatagramProtocol):
    """One UDP port per vehicle, as PX4 SITL gives each instance 14540 + i."""

    def __init__(self, vehicle: Vehicle) -> None:
        self.vehicle = vehicle

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.vehicle.transport = transport  # type: ignore[assignment]

    def datagram_received(self, data: bytes, addr: tuple[str, int]) -> None:
        v = self.vehicle
        if v.tlog is not None:  # (20 setpoints a tick in a lockstep swarm: no call when not recording)
            v.record(data)
        handlers.on_datagram(v, data, addr)

    def error_received(self, exc: Exception) -> None:
        # ICMP "port unreachable" after a client went away: normal for UDP telemetry.
        log.debug("vehicle %d: socket error %s", self.vehicle.sysid, exc)


class AutopilotHost:
    """Hosts `count` vehicles; vehicle i has sysid i + 1 (or `sysids[i]`) and listens on base_port + i.

    `signing_key` signs every vehicle's MAVLink with one key, `signing_keys[i]` vehicle i's
    with its own (None: unsigned); a signing vehicle drops and counts unsigned and badly
    signed input but the personality's `accept_unsigned` reports.
    `home_offsets_ned[i]` is where vehicle i's home (and local NED origin) sits in the
    mission frame, whose geodetic origin is `origin`. `streams` overrides the default
    telemetry rates (message name or id -> Hz of sim time; 0 disables). `boot` is "instant"
    (home and position at once) or "real" (the personality's measured start-up timeline).
    `params` sets parameters (emulator keys, SI units, e.g. {"offboard_loss_action": 5}) on
    every vehicle before it starts, as an operator's parameter file does.
    """

    def __init__(
        self,
        count: int,
        *,
        personality_name: str = "px4",
        vehicle: VehicleModel | str | Path = "quadrotor",
        origin: Origin | None = None,
        home_offsets_ned: Sequence[tuple[float, float, float]] | None = None,
        base_port: int = 14540,
        bind_host: str = "127.0.0.1",
        signing_key: bytes | None = None,
        signing_keys: Sequence[bytes | None] | None = None,
        gcs: tuple[str, int] | None = None,
        physics_hz: float = 50.0,
        streams: Mapping[str | int, float] | None = None,
        sysids: Sequence[int] | None = None,
        boot: str = "instant",
        stream_phases: int = STREAM_PHASES,
        params: Mapping[str, float] | None = None,
    ) -> None:
        if count < 1:
            raise ValueError("count must be >= 1")
        sysids = list(sysids) if sysids is not None else list(range(1, count + 1))
        if len(sysids) != count or not all(1 <= s <= MAX_SYSID for s in sysids):
            raise ValueError(
                f"need {count} system ids in 1..{MAX_SYSID} (MAVLink has 8-bit ids: more than {MAX_SYSID} "
                "vehicles need repeated ids, each on its own port)"
            )
        keys = list(signing_keys) if signing_keys is not None else [signing_key] * count
        if len(keys) != count:
            raise ValueError(f"{len(keys)} signing keys for {count} vehicles")
        if physics_hz < 50.0:
            raise ValueError("physics_hz must be >= 50 (the contract is >= 50 Hz of sim time)")
        self.personality: Personality = personality(personality_name)
        self.model = vehicle if isinstance(vehicle, VehicleModel) else load_vehicle(vehicle)
        self.origin = o = origin or Origin()
        offsets = list(home_offsets_ned or [(0.0, 0.0, 0.0)] * count)
        if len(offsets) != count:
            raise ValueError(f"home_offsets_ned has {len(offsets)} entries for {count} vehicles")
        self.home_offsets = torch.tensor(offsets, dtype=torch.float64).reshape(count, 3)
        self.base_port = base_port
        self.bind_host = bind_host
        self.gcs = gcs
        self.physics_dt = 1.0 / physics_hz
        rates = dict(telemetry.DEFAULT_RATES)
        for k, hz in (streams or {}).items():
            rates[telemetry.message_id(k)] = float(hz)
        self.boot = boot
        self.fleet = Fleet(count, Limits.ground_to_ceiling(self.model), rates,
                           Boot(boot_timeline(self.personality, boot)), stream_phases)
        self.vehicles = [
            Vehicle(
                self.fleet, i, sysids[i], self.personality, self.model,
                ned_to_geodetic(o.lat_deg, o.lon_deg, o.alt_m, offsets[i][0], offsets[i][1], 0.0),
                gcs=gcs, signing_key=keys[i], heartbeat=telemetry.heartbeat,
            )
            for i in range(count)
        ]
        for v in self.vehicles:
            for key, value in (params or {}).items():
                if key not in v.params.values:
                    raise ValueError(f"unknown vehicle parameter {key!r}")
                v.params.values[key] = float(value)
            v.params_changed()
        self._transports: list[asyncio.DatagramTransport] = []
        self._logged_drops: dict[int, int] = {}

    # ------------------------------------------------------------------ lifecycle
    @property
    def started(self) -> bool:
        """True while the vehicles' sockets are bound (between `start` and `close`)."""
        return bool(self._transports)

    async def start(self) -> None:
        """Bind one UDP socket per vehicle (127.0.0.1:base_port + i by default)."""
        loop = asyncio.get_running_loop()
        try:
            for v in self.vehicles:
                t, _ = await loop.create_datagram_endpoint(
                    lambda v=v: _VehicleProtocol(v), local_addr=(self.bind_host, self.base_port + v.index)
                )
                self._transports.append(t)  # type: ignore[arg-type]
                _grow_receive_buffer(t)
        except OSError:
            self.close()
            raise

    def record_tlogs(self, directory: str | Path) -> list[Path]:
        """Record each vehicle's MAVLink traffic (both ways) to DIR/vehicle<i>.tlog."""
        paths = []
        Path(directory).mkdir(parents=True, exist_ok=True)
        for i, v in enumerate(self.vehicles):
            paths.append(Path(directory) / f"vehicle{i}.tlog")
            v.tlog = open(paths[-1], "wb")  # noqa: SIM115 - closed in close()
        return paths

    def close(self) -> None:
        for t in self._transports:
            t.close()
        self._transports.clear()
        for v in self.vehicles:
            v.transport = None
            if v.tlog is not None:
                v.tlog.close()
                v.tlog = None

    async def __aenter__(self) -> AutopilotHost:
        await self.start()
        return self

    async def __aexit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ world-process API
    @property
    def count(self) -> int:
        return len(self.vehicles)

    @property
    def ports(self) -> list[int]:
        return [self.base_port + i for i in range(self.count)]

    def vehicle(self, i: int) -> Vehicle:
        return self.vehicles[i]

    @property
    def now(self) -> float:
        """Sim seconds since boot (the fleet's clock)."""
        return self.fleet.now

    @now.setter
    def now(self, t: float) -> None:  # tests of the SITL world set the clock by hand
        self.fleet.now = t

    def true_states(self) -> torch.Tensor:
        """(N, 6) float64 copy of [pos, vel] NED, each in its vehicle's local (home) frame.

        A normal tensor (the state itself lives in inference mode), safe to keep or use in autograd.
        """
        return torch.cat([self.fleet.pos, self.fleet.vel], dim=-1).clone()

    def mission_positions(self) -> torch.Tensor:
        """(N, 3) positions in the mission frame (local position + home offset)."""
        return (self.fleet.pos + self.home_offsets).clone()

    def kill(self, i: int) -> None:
        """Node failure: vehicle i stops answering and sending, and falls if airborne."""
        self.vehicles[i].kill()

    def place(self, i: int, pos_local: tuple[float, float, float]) -> None:
        """Put vehicle i at rest at `pos_local` (its local NED frame) with a zero acceleration
        setpoint in force, as if its companion had just sent one: a lockstep world starts the
        mission from the twin's start state exactly (the take-off before it is not lockstepped)."""
        f = self.fleet
        f.pos_np[i] = pos_local
        f.vel_np[i] = 0.0
        f.acc_np[i] = 0.0
        v = self.vehicles[i]
        if v.setpoint is not None and v.setpoint[0] == Kind.ACCEL:
            v.accept_setpoint(Kind.ACCEL, (0.0, 0.0, 0.0), v.setpoint[2])

    def set_gnss_noise(self, i: int, std_m: float) -> None:
        """GNSS noise: vehicle i's reported position gets Gaussian noise of `std_m` per axis (0: none)."""
        self.vehicles[i].gnss_noise_std_m = float(std_m)

    def set_gps(self, i: int, on: bool) -> None:
        """gps_loss: vehicle i's GPS receiver goes dark (on=False) or comes back."""
        v = self.vehicles[i]
        if on:
            v.restore_gps()
        else:
            v.lose_gps()

    def fail_motor(self, i: int) -> None:
        """motor_failure: one of vehicle i's motors stops for good."""
        self.vehicles[i].fail_motor()

    def counters(self) -> list[InputCounters]:
        return [v.counters for v in self.vehicles]

    def log_counters(self) -> None:
        """One warning line per vehicle whose dropped-input counters moved since the last call."""
        for v in self.vehicles:
            dropped = v.counters.dropped
            if dropped != self._logged_drops.get(v.index, 0):
                self._logged_drops[v.index] = dropped
                log.warning("vehicle %d: %d datagrams, dropped %s", v.sysid, v.counters.datagrams, v.counters.summary())

    # ------------------------------------------------------------------ the clock
    def advance(self, dt_s: float) -> None:
        """Move every vehicle forward by `dt_s` seconds of sim time (substeps <= physics_dt)."""
        if not dt_s > 0 or not math.isfinite(dt_s):
            return
        n = max(1, math.ceil(dt_s / self.physics_dt - 1e-9))
        h = dt_s / n
        for _ in range(n):
            self._substep(h)

    def advance_substeps(self, most: int, stop_at: float = math.inf) -> int:
        """Up to `most` substeps of physics_dt, as many `advance(physics_dt)` calls would do
        them, but the quiet ones (`Fleet.quiet_substeps`: nothing happens in them but
        physics) integrated in one call. Stops after the first substep at which anything
        else may happen (telemetry, a failsafe, a watched vehicle) or the clock reaches
        `stop_at`; returns how many substeps it did. The lockstep world moves its clock with
        it between telemetry samples."""
        h = self.physics_dt
        count = self.fleet.quiet_substeps(h, most, stop_at)
        self.fleet.step_many(h, count)
        self._after_physics()
        return count

    def _substep(self, h: float) -> None:
        self.fleet.step(h)
        self._after_physics()

    def _after_physics(self) -> None:
        """A substep's work after its physics: state machines, failsafes, telemetry."""
        f = self.fleet
        for i in f.watched():
            if not self.vehicles[i].update(f.now):
                f.unwatch(i)
        for i in f.setpoints_lost():
            self.vehicles[i].check_setpoint_loss(f.now)
        for i in f.gps_lost:
            self.vehicles[i].gps_update(f.now)
        self._boot_events()
        due: dict[int, list[int]] = {}
        for vi, msgid in f.streams.pop_due(f.now):
            due.setdefault(vi, []).append(msgid)
        for vi, ids in due.items():  # one datagram per vehicle and substep
            v = self.vehicles[vi]
            if v.peers or self.gcs is not None:
                v.send_bundle([telemetry.BUILDERS[msgid](v) for msgid in ids])

    def _boot_events(self) -> None:
        """Start-up on the real timeline: its STATUSTEXTs, and home and origin sent unasked
        when the EKF sets its origin (as ArduPilot does)."""
        boot, now = self.fleet.boot, self.fleet.now
        if boot.timeline is None:
            return
        texts = boot.due_texts(now)
        origin = boot.origin_just_set(now)
        for v in self.vehicles:
            for text in texts:
                v.statustext(text)
            if origin:
                v.send_bundle([telemetry.home_position(v), telemetry.gps_global_origin(v)])
