"""The deployable agent: one asyncio process per UAV, next to its autopilot.

Startup: heartbeat (-> personality), position and home valid, setpoints streaming, mode
(PX4 OFFBOARD after the stream is up, ArduPilot GUIDED), arm and take off (or attach to
an airborne vehicle with `takeoff=False`), then wait for the mission start.

Flying, everything keyed to the VEHICLE clock (LOCAL_POSITION_NED.time_boot_ms), so a
`--speedup` run behaves like a real-time one. Mission second k = boot_s - t0:

* at k (k % T_up == 0): publish the autopilot-reported state to tx/<id>;
* at the first telemetry of second k (at a signalling instant: once the updates of
  instant k have had time to arrive, see `_second_due`): close the signalling
  instant (misses, drops, failure state f), advance Algorithm 1's tracker one second
  (`predictor.pt`), and every tau seconds run `policy.pt` on
  (ego, beliefs, N_i mask, sensing features, f) -> acceleration, held until the next decision;
* every telemetry message (10 Hz of vehicle time) re-sends the current setpoint
  (type_mask 0x0C3F), with a wall-clock watchdog so the stream never stops while the
  process lives.

A broker outage only stops updates: the tracker keeps predicting, the bus reconnects with
backoff. Stop (Ctrl-C/SIGTERM): hold (PX4 AUTO.LOITER) or brake (ArduPilot BRAKE), exit.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import gc
import json
import logging
import math
import os
import random
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

import torch

from plmarl_sitl.deploy.agent.frames import home_offset_ned
from plmarl_sitl.deploy.agent.guard import band_guard
from plmarl_sitl.deploy.agent.neighbours import NeighbourTable
from plmarl_sitl.deploy.mavlink.client import VehicleLink
from plmarl_sitl.deploy.mavlink.connect import connect
from plmarl_sitl.deploy.mavlink.personality import personality
from plmarl_sitl.deploy.mqtt.schema import (
    INSTANT_WAIT_MIN_S,
    INSTANT_WAIT_WALL_S,
    Malformed,
    RxCounters,
    SeqFilter,
    StateMsg,
    Topics,
    decode_json,
    decode_sense,
    decode_state,
    encode_state,
    split_states,
)
from plmarl_sitl.deploy.mqtt.transport import MqttBus
from plmarl_sitl.errors import CommandRejected, UserError, VehicleTimeout
from plmarl_sitl.learning.nn.io import LoadedPolicy
from plmarl_sitl.mission import Mission
from plmarl_sitl.model.coverage import SENSING_FEATURES, sensing_features

log = logging.getLogger("plmarl.agent")

# LOCAL_POSITION_NED rate we ask for (vehicle time); one setpoint goes out per message, so
# this is also the setpoint rate (>= 10 Hz; PX4 needs > 2 Hz). 20 Hz doubles the load on a
# SITL world of 20 vehicles at speedup 10 for no gain in a policy acting every 3 s.
TELEMETRY_HZ = 10.0
HOLD_KP, HOLD_KD, HOLD_MAX_ACCEL = 0.3, 1.0, 2.5  # pre-mission hold: soft, so loop delays cannot make it ring
WATCHDOG_S = 0.1  # wall: re-send the setpoint if telemetry stalls (>= 10 Hz)
HOME_POSITION_ID = 242  # MAVLINK_MSG_ID_HOME_POSITION
UNUSED_STREAMS = {"ATTITUDE": 0.0, "POSITION_TARGET_LOCAL_NED": 0.0, "GLOBAL_POSITION_INT": 1.0}
REENGAGE_EVERY_S = 2.0  # wall: how often to ask for the offboard mode back after a failsafe


@dataclass(frozen=True)
class AgentConfig:
    uav_id: int
    connect_url: str
    broker_url: str
    mission: Mission
    autopilot: str = "auto"  # auto | px4 | ardupilot
    tup_s: int | None = None  # None: mission.signalling.tup_s
    swarm: str = "sitl"
    bus_mode: str = "sitl"  # sitl: the world relays tx -> rx/<id>; direct: subscribe tx/+
    takeoff: bool = True
    wait_start: bool = True  # wait for the world's start announcement (else start now)
    settle_min_s: float = 0.1  # vehicle s: an instant is never closed earlier than this
    settle_wall_s: float = INSTANT_WAIT_WALL_S  # wall s: ... and at most this late (x the observed speedup, >= INSTANT_WAIT_MIN_S)
    connect_timeout_s: float = 30.0
    takeoff_timeout_s: float = 120.0  # vehicle seconds
    trace_path: Path | None = None
    stats_path: Path | None = None


@dataclass
class LoopStats:
    """Decision-loop timing: telemetry message handled -> setpoint sent (wall ms)."""

    all_ms: deque[float] = field(default_factory=lambda: deque(maxlen=200_000))
    decision_ms: deque[float] = field(default_factory=lambda: deque(maxlen=200_000))
    # CPU time of the same ticks: what the code costs, without the time the OS gave the
    # core to other processes mid-tick (which the wall figure includes on a loaded machine).
    decision_cpu_ms: deque[float] = field(default_factory=lambda: deque(maxlen=200_000))
    # From the telemetry datagram's arrival in the kernel (UDP links): also the time the
    # message waited for this process to get a CPU and read it.
    decision_arrival_ms: deque[float] = field(default_factory=lambda: deque(maxlen=200_000))
    startup_s: float | None = None
    decisions: int = 0
    seconds: int = 0

    def summary(self) -> dict[str, float | int | None]:
        def pct(xs: deque[float], q: float) -> float | None:
            if not xs:
                return None
            s = sorted(xs)
            return s[min(len(s) - 1, int(q * len(s)))]

        return {
            "loop_p50_ms": pct(self.decision_ms, 0.5),
            "loop_p99_ms": pct(self.decision_ms, 0.99),
            "loop_cpu_p50_ms": pct(self.decision_cpu_ms, 0.5),
            "loop_cpu_p99_ms": pct(self.decision_cpu_ms, 0.99),
            "arrival_p50_ms": pct(self.decision_arrival_ms, 0.5),
            "arrival_p99_ms": pct(self.decision_arrival_ms, 0.99),
            "all_p50_ms": pct(self.all_ms, 0.5),
            "all_p99_ms": pct(self.all_ms, 0.99),
            "startup_s": self.startup_s,
            "decisions": self.decisions,
            "seconds": self.seconds,
        }


def rss_mb() -> float:
    try:
        import psutil

        return float(psutil.Process().memory_info().rss / 2**20)
    except Exception:  # noqa: BLE001 - best effort
        return float("nan")


def process_start_time() -> float:
    """Unix time this process started (so start-up includes the interpreter and imports).

    From /proc/self/stat's start time (clock ticks since boot) and CLOCK_BOOTTIME, both
    on the boot clock: good to a tick (10 ms). psutil's create_time() adds the tick count
    to /proc/stat's btime, which is truncated to a whole second, so it can place the start
    up to a second too early."""
    try:
        with open("/proc/self/stat") as f:
            ticks = int(f.read().rsplit(")", 1)[1].split()[19])
        age = time.clock_gettime(time.CLOCK_BOOTTIME) - ticks / os.sysconf("SC_CLK_TCK")
        return time.time() - age
    except (OSError, ValueError, IndexError, AttributeError):  # not Linux: count from now
        return time.time()


class Agent:
    def __init__(self, cfg: AgentConfig, lp: LoadedPolicy) -> None:
        self.cfg = cfg
        m = cfg.mission
        self.mission = m
        self.n = m.n_uavs
        if not 0 <= cfg.uav_id < self.n:
            raise UserError(f"--id {cfg.uav_id}: the mission has {self.n} UAVs (ids 0..{self.n - 1})")
        self.me = cfg.uav_id
        self.tracker, self.policy = lp.tracker, lp.policy
        self.vm = m.vehicle_model()
        self.tup = int(cfg.tup_s or m.signalling.tup_s)
        self.tau = int(m.timing.decision_every_s)
        self.topics = Topics(cfg.swarm)
        self.table = NeighbourTable(self.n, self.me, m.signalling.drop_after_missed)
        self.rx = RxCounters()
        self.seq_filter = SeqFilter()
        self.session = random.getrandbits(16)
        self.seq = 0
        subs = [self.topics.sense(self.me), self.topics.start, self.topics.ctl]
        subs += [self.topics.tx("+")] if cfg.bus_mode == "direct" else [self.topics.rx(self.me), self.topics.closed]
        self.bus = MqttBus(cfg.broker_url, f"plmarl-{cfg.swarm}-agent-{self.me}-{self.session:04x}", subs, self._on_message,
                           name=f"agent{self.me}-bus")
        self.link: VehicleLink | None = None
        self.stats = LoopStats()
        self.t_proc0 = process_start_time()
        self.stop_event = asyncio.Event()
        # Vehicle-side state
        self.home = torch.zeros(3)
        self.ego = torch.zeros(6)  # mission frame [p, v], latest telemetry
        self.boot_s = 0.0
        self.accel = (0.0, 0.0, 0.0)  # the command in force (before the band guard)
        self.hold_target: torch.Tensor | None = None
        self.flying = False
        # Mission clock and Algorithm 1 state
        self.t0: float | None = None
        self.next_pub_k: int | None = None
        self.next_k = 0
        self.ego_at: dict[int, torch.Tensor] = {}
        self.buf: torch.Tensor | None = None
        self.seen: torch.Tensor | None = None
        self.belief = torch.zeros(self.n, 6)
        self.aoi = torch.ones(self.n)
        self.closed_t = -math.inf  # last signalling instant the SITL link emulator closed
        # The last few sensing messages, (mission second, (K, 2) users in R_s): a decision at
        # k uses second k's users even when k+1's have already arrived (this agent ran late).
        self.sense_history: collections.deque[tuple[float, torch.Tensor]] = collections.deque(maxlen=8)
        self.used_sense_t: float | None = None
        self.sense_warned = False
        self.last_send_wall = 0.0
        self.rate: float | None = None
        self._rate_ref: tuple[float, float] | None = None
        self.first_k = 0
        self.next_close: int | None = None  # next signalling instant whose misses are unbooked
        self._sub_s = 0.0
        self._last_reengage = 0.0
        self._reengage_task: asyncio.Task | None = None
        self.reengaged = 0
        self._trace: IO[str] | None = None

    @torch.inference_mode()
    def warm_up(self, calls: int = 4) -> None:
        """Run tracker and policy on this agent's shapes a few times before flying.

        TorchScript's profiling executor records and optimises a graph over the first
        calls; done mid-flight that costs milliseconds on the first decisions. The
        tracker's state here is scratch, not the agent's."""
        n = self.n
        held = torch.zeros(n, 6)
        held[:, 0] = torch.arange(n, dtype=torch.float32) * 40.0
        buf, seen = self.tracker.init_state(held)
        for t in range(calls * 2):
            t_rx = torch.full((n,), float(t if t % 2 == 0 else t - 1))
            belief, _, buf, seen = self.tracker(float(t), held, t_rx, buf, seen)
            mask = torch.ones(n, dtype=torch.bool)
            mask[self.me] = False
            self.policy(held[self.me], belief, mask, torch.zeros(SENSING_FEATURES), torch.tensor(t % 4 == 3))
        sensing_features(held[:1, :3], torch.zeros(3, 2), self.mission.radii.sensing_m, self.mission.users.cluster_size)

    # ------------------------------------------------------------------ bus input
    def _on_message(self, topic: str, payload: bytes) -> None:
        t = self.topics
        if topic == t.sense(self.me):
            try:
                msg = decode_sense(payload)
            except Malformed as exc:
                self.rx.bad(f"sense_{exc.reason}")
                return
            self.sense_history.append((msg.t_ms / 1000.0, torch.tensor(msg.users, dtype=torch.float32).reshape(-1, 2)))
        elif topic == t.start:
            if not payload:
                return  # the world clears a previous run's retained start with an empty payload
            try:
                obj = decode_json(payload)
                t0 = float(obj["t0_boot_s"])
            except (Malformed, KeyError, TypeError, ValueError):
                self.rx.bad("start")
                return
            n = obj.get("n_uavs", self.n)
            if n != self.n:
                log.error("the world has %s UAVs, this agent was started for %d (--n-uavs)", n, self.n)
            if self.t0 is None and self.cfg.wait_start:
                self._set_t0(t0)
        elif topic == t.closed:
            try:
                self.closed_t = max(self.closed_t, float(decode_json(payload)["t_s"]))
            except (Malformed, KeyError, TypeError, ValueError):
                self.rx.bad("closed")
        elif topic == t.ctl:
            if not payload:
                return
            try:
                tup = int(decode_json(payload)["tup_s"])
            except (Malformed, KeyError, TypeError, ValueError):
                self.rx.bad("ctl")
                return
            if tup >= 1 and tup != self.tup:
                log.info("T_up changed %d -> %d s", self.tup, tup)
                self.tup = tup
                if self.t0 is not None:
                    k = math.ceil(self.boot_s - self.t0)
                    self.next_pub_k = -(-k // tup) * tup
                    self.next_close = self.next_pub_k
        else:
            self._on_state(payload)

    def _on_state(self, payload: bytes) -> None:
        try:
            parts = split_states(payload)
        except Malformed as exc:
            self.rx.bad(exc.reason)
            return
        for part in parts:
            self._on_one_state(part)

    def _on_one_state(self, payload: bytes) -> None:
        try:
            msg = decode_state(payload)
        except Malformed as exc:
            self.rx.bad(exc.reason)
            return
        if msg.sender == self.me:
            self.rx.self_echo += 1
            return
        if not 0 <= msg.sender < self.n:
            self.rx.unknown_sender += 1
            return
        why = self.seq_filter.check(msg)
        if why == "duplicate":
            self.rx.duplicate += 1
        elif why == "out_of_order":
            self.rx.out_of_order += 1
        elif self.table.on_state(msg.sender, msg.t_s, msg.state):
            self.rx.accepted += 1
        else:
            self.rx.out_of_order += 1

    # ------------------------------------------------------------------ clock
    def _set_t0(self, t0: float) -> None:
        self.t0 = t0
        k = max(0, math.ceil(self.boot_s - t0 - 1e-9))
        self.next_k = self.first_k = k
        self.next_close = -(-k // self.tup) * self.tup
        self.next_pub_k = -(-k // self.tup) * self.tup
        log.info("mission clock: t0 = boot %.3f s (first second %d)", t0, k)

    def _on_telemetry(self, m: object) -> None:
        """One LOCAL_POSITION_NED: advance the mission clock, decide, send the setpoint."""
        t_in = time.perf_counter()
        c_in = time.thread_time()
        self.boot_s = m.time_boot_ms / 1000.0  # type: ignore[attr-defined]
        self._track_rate()
        local = torch.tensor([m.x, m.y, m.z, m.vx, m.vy, m.vz], dtype=torch.float32)  # type: ignore[attr-defined]
        self.ego = torch.cat([local[:3] + self.home, local[3:]])
        decided = False
        if self.t0 is not None:
            tm = self.boot_s - self.t0
            while self.next_pub_k is not None and tm >= self.next_pub_k - 1e-9:
                self._publish_state(self.next_pub_k)
                self.next_pub_k += self.tup
            for k in range(self.next_k, math.floor(tm + 1e-9) + 1):
                self.ego_at.setdefault(k, self.ego.clone())  # state at the first sample of second k
            while self._second_due(self.next_k, tm):
                self._sub_s = max(0.0, tm - self.next_k)
                decided |= self._second(self.next_k)
                self.next_k += 1
        if self.flying:
            self._send_setpoint()
        dt_ms = (time.perf_counter() - t_in) * 1e3
        self.stats.all_ms.append(dt_ms)
        if decided:
            self.stats.decision_ms.append(dt_ms)
            self.stats.decision_cpu_ms.append((time.thread_time() - c_in) * 1e3)
            rx_ns = getattr(m, "rx_ns", None)
            if rx_ns is not None:
                self.stats.decision_arrival_ms.append((time.time_ns() - rx_ns) / 1e6)

    def _track_rate(self) -> None:
        """Vehicle seconds per wall second (the SITL speedup; 1 on a real vehicle)."""
        now = time.perf_counter()
        if self._rate_ref is None:
            self._rate_ref = (now, self.boot_s)
            return
        w0, b0 = self._rate_ref
        if now - w0 >= 1.0:
            r = (self.boot_s - b0) / (now - w0)
            if r > 0:
                self.rate = r if self.rate is None else 0.5 * self.rate + 0.5 * r
            self._rate_ref = (now, self.boot_s)

    def settle_max_s(self) -> float:
        return max(INSTANT_WAIT_MIN_S, self.cfg.settle_wall_s * (self.rate or 1.0))

    def _second_due(self, k: int, tm: float) -> bool:
        """Second k can be processed: at once, except
        - at a signalling instant, which waits until every neighbour expected to deliver has
          (those in N_i; at the first instant, everyone) or the SITL link emulator says the
          instant is closed, and
        - at the first decision, which waits for a first sensing message (is there a
          sensing publisher at all?); later decisions take the newest sensing there is,
          as a wait for second k's would delay every action by the bus's round trip,
        both bounded by `settle_max_s` of vehicle time, so late messages still count."""
        if tm < k - 1e-9:
            return False
        instant = k % self.tup == 0
        first_sensing = k % self.tau == 0 and not self.sense_history and not self.sense_warned
        if not instant and not first_sensing:
            return True
        if instant and tm < k + self.cfg.settle_min_s:
            return False
        if tm >= k + self.settle_max_s():
            return True
        if first_sensing:
            return False
        if self.closed_t >= k:
            return True
        t_rx = self.table.t_rx
        return all(float(t_rx[j]) == k for j in self._expected(k))

    def _expected(self, k: int) -> list[int]:
        """Neighbours whose update for instant k we wait for: at the first instant everyone;
        later those in N_i that the tracker believes within R_comm (one that has flown out
        of range will not deliver, and waiting for it would only delay the decision)."""
        others = [j for j in range(self.n) if j != self.me]
        if k == self.first_k:
            return others
        r2 = self.mission.radii.comm_m ** 2
        d = self.belief[:, :3] - self.ego[:3]
        near = (d * d).sum(-1) <= r2
        return [j for j in others if self.table.in_set(j) and bool(near[j])]

    def _publish_state(self, k: int) -> None:
        state = tuple(float(x) for x in self.ego.tolist())
        msg = StateMsg(self.me, self.session, self.seq, k * 1000, state)  # type: ignore[arg-type]
        self.seq += 1
        self.bus.publish(self.topics.tx(self.me), encode_state(msg))

    # ------------------------------------------------------------------ Algorithm 1
    @torch.inference_mode()
    def _book_misses(self, k: int) -> None:
        """Book the misses of every signalling instant whose grace period has passed by
        second k (the instant itself when the grace is under a second)."""
        while self.next_close is not None and self.next_close + self.grace_s() <= k + self._sub_s:
            inst = self.next_close
            for j in self.table.close_instant(float(inst)):
                log.warning("neighbour %d dropped at t = %d s (%d signalling instants missed); f = 1", j, k, self.table.drop)
            self.next_close = inst + self.tup

    def grace_s(self) -> float:
        """How long after an instant an update still counts as delivered: 0.5 s of wall
        time (x the observed speedup), at least the decision wait, at most T_up / 2."""
        return min(max(self.settle_max_s(), 0.5 * (self.rate or 1.0)), self.tup / 2)

    def _second(self, k: int) -> bool:
        """Mission second k: close the instant, advance the tracker, maybe decide."""
        self.stats.seconds += 1
        self._book_misses(k)
        held, t_rx = self.table.state, self.table.t_rx
        if self.buf is None:
            self.buf, self.seen = self.tracker.init_state(held)
        self.belief, self.aoi, self.buf, self.seen = self.tracker(float(k), held, t_rx, self.buf, self.seen)
        decided = k % self.tau == 0
        ego = self.ego_at.pop(k, self.ego)
        for old in [s for s in self.ego_at if s < k]:
            del self.ego_at[old]
        mask = self.table.mask()
        if decided:
            sense = self._sense(ego, k)
            fail = torch.tensor(self.table.lost)
            a = self.policy(ego, self.belief, mask, sense, fail)
            self.accel = (float(a[0]), float(a[1]), float(a[2]))
            self.stats.decisions += 1
        if self._trace is not None:
            rec = {
                "t": k,
                "boot_s": round(self.boot_s, 3),
                "aoi": [round(float(x), 2) for x in self.aoi],
                "mask": [bool(x) for x in mask],
                "t_rx": [None if x < -1e8 else float(x) for x in self.table.t_rx.tolist()],
                "fail": self.table.lost,
                "ego": [round(x, 2) for x in ego.tolist()],
                "accel": [round(x, 3) for x in self.accel],  # the policy's command
                "cmd": [round(x, 3) for x in self._command()],  # after the band guard
                "decided": decided,
                "sense_t": self.used_sense_t,  # the mission second of the users the last decision saw
            }
            self._trace.write(json.dumps(rec) + "\n")
        return decided

    def _sense(self, ego: torch.Tensor, k: int) -> torch.Tensor:
        """Sensing features of the newest users' message not after second k (usually
        second k - 1: the world publishes second k's a moment after its telemetry)."""
        m = self.mission
        if not self.sense_history:
            if not self.sense_warned:
                self.sense_warned = True
                log.warning("no sensing publisher on %s: flying as if no users are sensed", self.topics.sense(self.me))
            return torch.zeros(SENSING_FEATURES)
        t, users = next(((t, u) for t, u in reversed(self.sense_history) if t <= k + 1e-6), self.sense_history[0])
        self.used_sense_t = t
        return sensing_features(ego[:3].unsqueeze(0), users, m.radii.sensing_m, m.users.cluster_size)[0]

    # ------------------------------------------------------------------ setpoints
    def _command(self) -> tuple[float, float, float]:
        vm = self.vm
        alt, v_up = -float(self.ego[2]), -float(self.ego[5])
        if self.t0 is None or self.boot_s < self.t0:
            # Before the mission: hold where offboard control began (PD on position).
            tgt = self.hold_target if self.hold_target is not None else self.ego[:3]
            a = HOLD_KP * (tgt - self.ego[:3]) - HOLD_KD * self.ego[3:]
            norm = float(torch.linalg.vector_norm(a))
            if norm > HOLD_MAX_ACCEL:
                a = a * (HOLD_MAX_ACCEL / norm)
            return float(a[0]), float(a[1]), float(a[2])
        return band_guard(self.accel, alt, v_up, vm.min_alt_m, vm.max_alt_m, vm.max_accel_mps2)

    def _send_setpoint(self) -> None:
        assert self.link is not None
        self.link.send_accel_ned(*self._command())
        self.last_send_wall = time.perf_counter()

    async def _watchdog(self) -> None:
        """>= 10 Hz wall even if telemetry stalls (PX4 leaves OFFBOARD after 1 s without)."""
        while True:
            await asyncio.sleep(WATCHDOG_S / 2)
            if self.flying and time.perf_counter() - self.last_send_wall >= WATCHDOG_S:
                self._send_setpoint()

    async def _gcs_heartbeat(self) -> None:
        """A companion computer announces itself at 1 Hz (autopilots track their peers)."""
        while True:
            if self.link is not None:
                self.link.send_heartbeat()
            await asyncio.sleep(1.0)

    # ------------------------------------------------------------------ startup
    async def _wait_until(self, what: str, cond: object, timeout_s: float) -> None:
        """Wait on telemetry until cond() holds; timeout in VEHICLE seconds (speedup-safe)."""
        assert self.link is not None
        start = self.boot_s
        while not cond():  # type: ignore[operator]
            m = await self.link.recv("LOCAL_POSITION_NED", 5.0)
            self._on_telemetry(m)
            if self.boot_s - start > timeout_s:
                raise VehicleTimeout(self.link.sysid, what, timeout_s)

    def _alt(self) -> float:
        return -float(self.ego[2])

    async def _set_mode(self, name: str) -> None:
        assert self.link is not None
        for attempt in range(5):
            try:
                await self.link.set_mode(name)
                return
            except CommandRejected as exc:
                if exc.result_name != "MAV_RESULT_TEMPORARILY_REJECTED" or attempt == 4:
                    raise
                await asyncio.sleep(0.2)

    async def _startup(self) -> None:
        cfg = self.cfg
        self.warm_up()
        link = connect(cfg.connect_url)
        link.stamp_arrivals = cfg.stats_path is not None  # only when measuring (one ioctl per datagram)
        self.link = link
        try:
            await link.open(timeout=cfg.connect_timeout_s)
        except VehicleTimeout as exc:
            raise UserError(f"no autopilot heartbeat on {cfg.connect_url} within {cfg.connect_timeout_s:g} s") from exc
        assert link.personality is not None
        seen = link.personality.name
        if cfg.autopilot != "auto":
            if cfg.autopilot != seen:
                raise UserError(f"--autopilot {cfg.autopilot}, but the vehicle's heartbeat says {seen}")
            link.personality = personality(cfg.autopilot)
        p = link.personality
        log.info("vehicle sysid %d on %s: %s personality (heartbeat at %.2f s)", link.sysid, cfg.connect_url, p.name,
                 time.time() - self.t_proc0)
        await link.set_message_interval("LOCAL_POSITION_NED", TELEMETRY_HZ)
        home = await link.request("HOME_POSITION", HOME_POSITION_ID, timeout=3.0)
        self.home = torch.tensor(home_offset_ned(self.mission.origin, home.latitude / 1e7, home.longitude / 1e7, home.altitude / 1000.0),
                                 dtype=torch.float32)
        self._on_telemetry(await link.recv("LOCAL_POSITION_NED", 5.0))
        # Start-up ends here: policy loaded, autopilot found, position and home valid.
        # What follows (arming, climbing) is the vehicle's time, not the agent's.
        self.stats.startup_s = time.time() - self.t_proc0
        log.info("ready after %.2f s (process start -> telemetry and home valid), RSS %.0f MB", self.stats.startup_s, rss_mb())
        # Streams the agent does not use cost the autopilot link (and, in SITL, the
        # world's CPU) for nothing; our MAVLink instance is ours alone, a GCS has its own.
        for name, hz in UNUSED_STREAMS.items():
            with contextlib.suppress(CommandRejected, VehicleTimeout):
                await link.set_message_interval(name, hz)
        # Everything alive now (torch, the policy, the loop) lives for the whole flight:
        # freezing it keeps full GC passes from walking ~10^5 objects mid-decision. Done
        # here, on the ground, because the collection itself takes a while.
        gc.collect()
        gc.freeze()
        hb = link.latest.get("HEARTBEAT")
        armed = bool(hb and hb.base_mode & 128)
        alt_tgt = min(max(self.vm.takeoff_alt_m, self.vm.min_alt_m), self.vm.max_alt_m)
        if cfg.takeoff and not armed:
            if p.takeoff_needs_offboard_mode:  # ArduPilot: GUIDED, arm, NAV_TAKEOFF
                await self._set_mode(p.offboard_mode)
                await link.arm()
                await link.takeoff(alt_tgt)
            else:  # PX4: arm, AUTO.TAKEOFF, then OFFBOARD once the stream is up
                await link.arm()
                await link.takeoff(alt_tgt, home_amsl_m=home.altitude / 1000.0)
            await self._wait_until(
                "takeoff", lambda: self._alt() >= alt_tgt - 0.5 and abs(float(self.ego[5])) < 0.3, cfg.takeoff_timeout_s
            )
        elif not armed:
            raise UserError("--no-takeoff: the vehicle is not armed (attach only to a flying vehicle)")
        # PX4 refuses OFFBOARD until setpoints stream: stream first (hold here), then switch.
        self.hold_target = self.ego[:3].clone()
        self.flying = True
        for _ in range(5):
            self._on_telemetry(await link.recv("LOCAL_POSITION_NED", 5.0))
        await self._set_mode(p.offboard_mode)
        log.info("in %s at %.1f m, %.2f s after process start", p.offboard_mode, self._alt(), time.time() - self.t_proc0)

    # ------------------------------------------------------------------ main
    async def _fly(self) -> None:
        assert self.link is not None
        if not self.cfg.wait_start and self.t0 is None:
            self._set_t0(await self._common_epoch())
        while not self.stop_event.is_set():
            m = await self.link.recv("LOCAL_POSITION_NED", 5.0)
            self._on_telemetry(m)
            self._check_mode()

    async def _common_epoch(self) -> float:
        """t0 on this vehicle's boot clock that every agent of the swarm agrees on, with no
        world to announce it: the last UTC midnight of the autopilot's (GPS-disciplined)
        SYSTEM_TIME. Signalling instants are then multiples of T_up since midnight on every
        vehicle. Without a unix time (no GPS yet) fall back to boot time 0, which agrees
        only between vehicles that booted together (one SITL host)."""
        assert self.link is not None
        try:
            st = await self.link.recv("SYSTEM_TIME", 5.0)
        except VehicleTimeout:
            st = None
        if st is None or st.time_unix_usec == 0:
            log.warning("no SYSTEM_TIME unix time from the autopilot: signalling instants follow its boot clock")
            return 0.0
        unix_s = st.time_unix_usec / 1e6
        offset = unix_s - st.time_boot_ms / 1e3  # unix time at boot
        return math.floor(unix_s / 86400.0) * 86400.0 - offset

    def _check_mode(self) -> None:
        """If the autopilot left the offboard mode on its own (a setpoint-loss failsafe
        after a stall of this process), ask for it back once the stream is flowing again,
        at most every REENGAGE_EVERY_S. A mode a pilot chose is left alone: only the
        personality's failsafe hold mode triggers this."""
        link = self.link
        assert link is not None and link.personality is not None
        hb = link.latest.get("HEARTBEAT")
        if hb is None or hb.get_srcComponent() != 1:
            return
        p = link.personality
        mode = p.mode_by_custom(hb.custom_mode)
        if mode is None or mode.name != p.hold_mode or not hb.base_mode & 128:
            return
        now = time.perf_counter()
        if now - self._last_reengage < REENGAGE_EVERY_S or self._reengage_task is not None and not self._reengage_task.done():
            return
        self._last_reengage = now
        self.reengaged += 1
        log.warning("vehicle fell back to %s (setpoint-loss failsafe); re-engaging %s", mode.name, p.offboard_mode)
        self._reengage_task = asyncio.ensure_future(self._reengage(p.offboard_mode))

    async def _reengage(self, mode: str) -> None:
        try:
            async with asyncio.timeout(3.0):
                await self._set_mode(mode)
        except (TimeoutError, VehicleTimeout, CommandRejected) as exc:
            log.error("could not re-engage %s: %s", mode, exc)

    async def _hold(self) -> None:
        """Ctrl-C: hand the vehicle to its own hold (PX4 AUTO.LOITER) or brake (ArduPilot)."""
        link = self.link
        if link is None or link.personality is None or not self.flying:
            return
        mode = "BRAKE" if link.personality.name == "ardupilot" else link.personality.hold_mode
        try:
            async with asyncio.timeout(3.0):
                await self._set_mode(mode)
            log.warning("stopped: vehicle in %s", mode)
        except (TimeoutError, VehicleTimeout, CommandRejected) as exc:
            log.error("stopped, but could not command %s: %s (the autopilot's own failsafe takes over)", mode, exc)

    async def run(self) -> int:
        """Run until `stop_event` is set (signal handler) or the vehicle goes silent."""
        torch.set_num_threads(1)
        if self.cfg.trace_path is not None:
            self._trace = open(self.cfg.trace_path, "w", buffering=1)  # noqa: SIM115 - closed in finally
        code = 0
        try:
            async with asyncio.TaskGroup() as tg:
                helpers = [
                    tg.create_task(self.bus.run(), name="bus"),
                    tg.create_task(self._gcs_heartbeat(), name="gcs-heartbeat"),
                    tg.create_task(self._watchdog(), name="setpoint-watchdog"),
                ]
                main = tg.create_task(self._main(), name="main")
                helpers.append(tg.create_task(self._cancel_on_stop(main), name="stop-watch"))
                # The helpers only serve `main`: when it ends, so do they.
                main.add_done_callback(lambda _t: [h.cancel() for h in helpers])
        except* VehicleTimeout as eg:
            log.error("vehicle lost: %s", eg.exceptions[0])
            code = 3
        finally:
            await self._hold()
            if self.link is not None:
                self.link.close()
            if self._trace is not None:
                self._trace.close()
            self._write_stats()
        return code

    async def _cancel_on_stop(self, main: asyncio.Task) -> None:
        await self.stop_event.wait()
        main.cancel()

    async def _main(self) -> None:
        try:
            await self._startup()
            await self._fly()
        except asyncio.CancelledError:
            if not self.stop_event.is_set():
                raise  # cancelled from outside: propagate; a requested stop ends quietly

    def _write_stats(self) -> None:
        if self.cfg.stats_path is None:
            return
        out = {
            **self.stats.summary(),
            "rss_mb": rss_mb(),
            "decision_ms_samples": [round(x, 4) for x in list(self.stats.decision_ms)[-5000:]],
            "decision_cpu_ms_samples": [round(x, 4) for x in list(self.stats.decision_cpu_ms)[-5000:]],
            "decision_arrival_ms_samples": [round(x, 4) for x in list(self.stats.decision_arrival_ms)[-5000:]],
            "rx": self.rx.as_dict(),
            "bus": self.bus.stats.as_dict(),
            "dropped": self.table.dropped,
            "reengaged": self.reengaged,
            "fail": self.table.lost,
            "pid": os.getpid(),
        }
        Path(self.cfg.stats_path).write_text(json.dumps(out))
