"""The recorded events of a run (events.jsonl), named as a reader of the report wants them.

An entry is {"t", "type", ...} as `plmarl swarm up` recorded it: the mission's scripted
events (node_failure, link_blackout, broker_outage, tup_change, gnss_noise, gps_loss,
motor_failure, with their fields), the ends of the windowed ones that the launcher
switches ("broker_outage_end", ...), what an autopilot under a fault said ("autopilot"),
and the UAVs the run lost ("uav_failed": an autopilot fault took it out; "agent_failed":
lockstep declared its agent failed). The plots, the HTML report and the live map all
take their wording from here, so one event reads the same everywhere.
"""

from __future__ import annotations

from dataclasses import dataclass

# Events after which a UAV no longer counts: the plots mark where and when it stopped. (A
# motor_failure or gps_loss takes a UAV out through the "uav_failed" entry that follows it.)
LOSS_TYPES = ("node_failure", "uav_failed", "agent_failed")
# Entries that only close a window or report what a vehicle said: no marker of their own.
QUIET_TYPES = ("autopilot",)


@dataclass(frozen=True)
class Marker:
    """One thing to mark on a time axis: an instant (`end` None) or a window [t, end)."""

    t: float
    label: str
    kind: str  # the event type
    end: float | None = None
    uav: int | None = None


def _uavs_text(uavs: list[int] | tuple[int, ...] | None) -> str:
    if not uavs:
        return "all UAVs"
    return ("UAV " if len(uavs) == 1 else "UAVs ") + ", ".join(str(u) for u in uavs)


def event_label(ev: dict) -> str:
    """A short label: "UAV 2 fails", "link blackout (all UAVs, 40 s)", "T_up -> 5 s" ..."""
    kind = ev.get("type", "event")
    uav = ev.get("uav")
    dur = f", {ev['duration_s']:g} s" if ev.get("duration_s") is not None else ""
    if kind == "node_failure":
        return f"UAV {uav} fails"
    if kind == "uav_failed":
        return f"UAV {uav} lost ({str(ev.get('cause', 'fault')).replace('_', ' ')})"
    if kind == "agent_failed":
        return f"UAV {uav}'s agent failed"
    if kind == "motor_failure":
        return f"UAV {uav} motor failure"
    if kind == "gps_loss":
        return f"GPS loss ({_uavs_text(ev.get('uavs'))}{dur})"
    if kind == "link_blackout":
        return f"link blackout ({_uavs_text(ev.get('uavs'))}{dur})"
    if kind == "broker_outage":
        return f"broker outage{' (' + dur[2:] + ')' if dur else ''}"
    if kind == "tup_change":
        return f"T_up -> {ev.get('tup_s')} s"
    if kind == "gnss_noise":
        return f"GNSS noise {ev.get('std_m', '?')} m ({_uavs_text(ev.get('uavs'))}{dur})"
    if kind.endswith("_end"):
        return kind[: -len("_end")].replace("_", " ") + " ends"
    if kind == "autopilot":
        said = ", ".join(f"{k} {v}" for k, v in ev.items() if k not in ("t", "type", "uav"))
        return f"UAV {uav} autopilot: {said}"
    return kind.replace("_", " ")


def markers(events: list[dict], t_end: float) -> list[Marker]:
    """The events to draw on a time axis, in time order: windows for the events with a
    duration (or an "_end" entry), instants for the rest. A window without a recorded end
    or duration runs to `t_end`."""
    out = []
    for i, ev in enumerate(events):
        kind = ev.get("type", "event")
        if kind in QUIET_TYPES or kind.endswith("_end"):
            continue
        end = None
        if ev.get("duration_s") is not None:
            end = min(float(ev["t"]) + float(ev["duration_s"]), t_end)
        else:
            closing = next((e for e in events[i + 1:] if e.get("type") == f"{kind}_end"), None)
            if closing is not None:
                end = float(closing["t"])
            elif kind in ("gnss_noise", "gps_loss"):  # no duration: in force to the end
                end = t_end
        out.append(Marker(float(ev["t"]), event_label(ev), kind, end, ev.get("uav")))
    return sorted(out, key=lambda m: m.t)


def lost_at(events: list[dict]) -> dict[int, tuple[float, str]]:
    """{uav: (t, label)}: when each UAV the run lost stopped counting (its first loss)."""
    out: dict[int, tuple[float, str]] = {}
    for ev in sorted(events, key=lambda e: e["t"]):
        if ev.get("type") in LOSS_TYPES and ev.get("uav") is not None and ev["uav"] not in out:
            out[int(ev["uav"])] = (float(ev["t"]), event_label(ev))
    return out
