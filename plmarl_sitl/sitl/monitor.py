"""What an observer of a running swarm knows: the world's metrics plus the signalling it
can overhear on the bus (`tx/+`, `rx/+`).

From the deliveries it derives, per UAV, the neighbours it currently holds (heard within
`drop_after_missed` signalling intervals, the twin's N_i rule) and the largest P-AoI
among them, and the swarm's signalling rate. It turns that into the rows of
metrics.jsonl and into the live view's `SwarmView` (with a map when it was given the
mission: `map_source.MapSource`). Used in-process by `plmarl swarm up`
and over MQTT by `plmarl swarm status`.
"""

from __future__ import annotations

import collections
import math

from plmarl_sitl.deploy.mqtt.auth import AuthError
from plmarl_sitl.deploy.mqtt.schema import Malformed, Topics, decode_json
from plmarl_sitl.deploy.mqtt.wire import Wire
from plmarl_sitl.mission import Mission
from plmarl_sitl.sitl.live import SwarmView, UavView
from plmarl_sitl.sitl.map_source import MapSource
from plmarl_sitl.sitl.report_events import event_label

HISTORY_S = 120  # seconds of coverage kept for the sparkline


class SwarmMonitor:
    def __init__(self, swarm: str, tup_s: int, drop_after_missed: int, speedup: float = 1.0, wire: Wire | None = None,
                 mission: Mission | None = None, seed: int | None = None) -> None:
        self.topics = Topics(swarm)
        self.wire = wire or Wire(None)  # signed swarms: only authentic states are shown
        self.swarm = swarm
        self.tup_s = tup_s
        self.drop_after_missed = drop_after_missed
        self.speedup = speedup
        self.t: float | None = None  # last mission second seen in metrics
        self.last: dict | None = None  # last metrics message
        self.last_rx: dict[int, dict[int, float]] = collections.defaultdict(dict)  # [i][j] -> sample time (s)
        self.tx_times: collections.deque[float] = collections.deque()
        self.tx_total = 0
        self._tx_at_last_row = 0
        self.coverage: collections.deque[float] = collections.deque(maxlen=HISTORY_S)
        self.events: list[str] = []
        self.event_names: list[str] = []
        self.malformed = 0
        # With the mission (and its seed) the view carries a map; the users are replayed
        # only when a view is drawn, so a headless run pays nothing for it.
        self.map_source = MapSource(mission, mission.seed if seed is None else seed) if mission is not None else None

    # ------------------------------------------------------------------ inputs
    def on_bus(self, topic: str, payload: bytes) -> None:
        """A message overheard on the swarm's topics (tx, rx or metrics)."""
        who = self.topics.id_of(topic)
        if topic == self.topics.metrics:
            try:
                self.on_metrics(decode_json(payload))
            except Malformed:
                self.malformed += 1
            return
        if who is None:
            return
        try:
            msgs = [self.wire.read_state(part) for part in self.wire.split_states(payload)]
        except (Malformed, AuthError):
            self.malformed += 1
            return
        if topic == self.topics.tx(who):
            self.tx_total += len(msgs)
            self.tx_times.extend([self.t or 0.0] * len(msgs))
        elif topic == self.topics.rx(who):
            for msg in msgs:
                self.last_rx[who][msg.sender] = msg.t_s

    def on_metrics(self, m: dict) -> None:
        """The world's per-second metrics (see SitlWorld._second)."""
        self.last = m
        if m.get("tup_s"):
            self.tup_s = int(m["tup_s"])
        if m.get("t") is not None:
            self.t = float(m["t"])
            self.coverage.append(float(m["coverage"]))
            while self.tx_times and self.tx_times[0] < self.t - 60.0:
                self.tx_times.popleft()

    def on_event(self, event: dict | str) -> None:
        """An event as it fired: an events.jsonl entry ({"t", "type", ...}: the headless line
        gets "type@t", the live view its name, "UAV 2 fails at 100 s"), or a text for both."""
        if isinstance(event, str):
            self.events.append(event)
            self.event_names.append(event)
            return
        self.events.append(f"{event['type']}@{event['t']:.0f}")
        self.event_names.append(f"{event_label(event)} at {event['t']:.0f} s")

    # ------------------------------------------------------------------ derived
    def neighbours(self, i: int) -> dict[int, float]:
        """{j: P-AoI} of the neighbours i holds now (heard within the drop horizon)."""
        if self.t is None:
            return {}
        horizon = self.drop_after_missed * self.tup_s
        out = {}
        for j, t_rx in self.last_rx.get(i, {}).items():
            age = max(1.0, self.t - t_rx)
            if age < horizon + 1e-6:
                out[j] = age
        return out

    def aoi_max(self, i: int) -> float | None:
        held = self.neighbours(i)
        return max(held.values()) if held else None

    def messages_per_min(self) -> float:
        if self.t is None:
            return 0.0
        window = min(60.0, max(self.t, 1.0))
        return len(self.tx_times) * 60.0 / window

    def metrics_row(self) -> dict | None:
        """One metrics.jsonl row for the last mission second, or None before the start."""
        m = self.last
        if m is None or m.get("t") is None:
            return None
        messages = self.tx_total - self._tx_at_last_row
        self._tx_at_last_row = self.tx_total
        return {
            "t": m["t"],
            "coverage": m["coverage"],
            "lambda2": m["lambda2"],
            "messages": messages,
            "uavs": [
                # pos/vel are None while a vehicle reports none (an external autopilot that is not
                # streaming its local position: sitl/external.py::uav_rows leaves them out)
                {"id": u["id"], "alive": u["alive"], "pos_ned": u.get("pos"), "vel_ned": u.get("vel"),
                 "aoi_max": self.aoi_max(u["id"])}
                for u in m.get("uav", [])
            ],
        }

    def view(self) -> SwarmView:
        m = self.last or {}
        uavs = []
        for u in m.get("uav", []):
            held = self.neighbours(u["id"])
            if not u.get("alive", True):
                link = "dead"
            elif not held:
                link = "lost" if self.t is not None and self.t > self.tup_s else "?"
            else:
                link = "ok" if max(held.values()) <= self.tup_s else "stale"
            vel = u.get("vel", [math.nan] * 3)
            uavs.append(
                UavView(
                    id=u["id"], alive=u.get("alive", True), mode=u.get("mode", "?"), armed=bool(u.get("armed")),
                    pos_ned=tuple(u.get("pos", [math.nan] * 3)), speed=math.sqrt(sum(x * x for x in vel)),
                    neighbours=len(held), aoi_max=max(held.values()) if held else None,
                    last_action=tuple(u["acc"]) if u.get("acc") is not None else None, link=link,
                )
            )
        return SwarmView(
            swarm=self.swarm,
            t=float(m.get("t") if m.get("t") is not None else -1.0),
            coverage=float(m.get("coverage", math.nan)),
            coverage_history=tuple(self.coverage),
            lambda2=float(m.get("lambda2", math.nan)),
            messages_per_min=self.messages_per_min(),
            events_fired=tuple(self.events),
            events_named=tuple(self.event_names),
            speedup=self.speedup,
            uavs=tuple(uavs),
            map=self.map_source.view(m.get("t"), m.get("uav", [])) if self.map_source is not None else None,
        )
