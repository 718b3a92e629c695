"""docs/MISSIONS.md, the mission reference, generated from the schema so that it cannot drift.

Types, defaults and bounds come from the dataclasses of `mission.py` and their field
metadata; what a key means comes from FIELD_DOCS below, one line per key path. A key of
the schema without a line here fails `tests/test_mission_reference.py`, and so does a
docs/MISSIONS.md that is not what `python -m plmarl_sitl.mission_reference` writes.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
import types
import typing
from pathlib import Path
from typing import Any, Literal

from plmarl_sitl.config import REPO_ROOT, VehicleModel
from plmarl_sitl.mission import _EVENT_FIELDS, Mission

OUT = REPO_ROOT / "docs" / "MISSIONS.md"

FIELD_DOCS: dict[str, str] = {
    "name": "The mission's name: it names runs, cards and plots.",
    "seed": "Seed of everything random (user layout and motion, links, failures); `--seed` overrides it.",
    "n_uavs": "Swarm size N. Bounded by MAVLink's vehicle system ids 1..250.",
    "vehicle": "Vehicle model: a name in `vehicle_models/` (`quadrotor`) or a path to a YAML file of your own "
               "(absolute, or relative to the working directory; see *Vehicle models* below).",
    "area": "The square-cornered area users live in; the mission frame's origin is its south-west corner.",
    "area.north_m": "Extent north (m).",
    "area.east_m": "Extent east (m).",
    "users": "The ground users to cover.",
    "users.count": "Number of users; a multiple of `cluster_size`.",
    "users.cluster_size": "Users per cluster: `count / cluster_size` clusters.",
    "users.mobility": "User motion: Gauss-Markov, Random Waypoint inside the cluster disk, Reference Point Group "
                      "Mobility, or `mixed` (one of the three per episode, for training).",
    "users.max_speed_mps": "User speed limit (m/s).",
    "users.cluster_std_m": "Spread of a cluster's users around its centre (m, per axis).",
    "users.gm_alpha": "Gauss-Markov memory per second (1: straight lines, 0: white noise).",
    "users.layout": "`fixed` (the centres in `cluster_centers`), `lattice` (a centred grid `cluster_spacing_m` "
                    "apart) or `random` (a new connected layout per seed).",
    "users.cluster_centers": "`fixed` layout only: one `[north, east]` per cluster, inside the area. Keep each "
                             "within R_comm (`radii.comm_m`) of another, or one UAV per cluster cannot stay "
                             "connected (loading warns).",
    "users.cluster_spacing_m": "`lattice` layout: spacing of the grid (m).",
    "users.rpgm_range_m": "`rpgm` mobility: radius around its cluster's home within which a group picks its "
                          "waypoints, clamped into the area (m); 0: 2 `cluster_std_m`. Wide and fast: crowds "
                          "that walk across the area.",
    "channel": "Air-to-ground (Al-Hourani) and UAV-to-UAV radio (docs/ARCHITECTURE.md, *Coverage*, *Connectivity*).",
    "channel.environment": "Label of the environment (the parameters below define it).",
    "channel.los_a": "Al-Hourani LoS-probability parameter a.",
    "channel.los_b": "Al-Hourani LoS-probability parameter b.",
    "channel.eta_los_db": "Excess path loss in line of sight (dB).",
    "channel.eta_nlos_db": "Excess path loss without line of sight (dB).",
    "channel.carrier_ghz": "Air-to-ground carrier (GHz).",
    "channel.max_path_loss_db": "A user is covered when within `radii.sensing_m` and the mean A2G path loss is at "
                                "most this (dB): it sets the coverage radius per altitude.",
    "channel.u2u_carrier_ghz": "UAV-to-UAV carrier (GHz), free space.",
    "channel.tx_power_dbm": "UAV transmit power (dBm).",
    "channel.noise_dbm": "Receiver noise (dBm).",
    "channel.interference_activity": "Share of time another UAV transmits in the same slot (co-channel interference).",
    "channel.sinr_threshold_db": "A UAV-UAV link exists when the SINR is at least this both ways (dB).",
    "radii": "Ranges of the letter's Table I.",
    "radii.sensing_m": "R_s: a UAV covers and senses users within this ground distance (m).",
    "radii.comm_m": "R_comm: UAV-UAV links reach at most this far (m).",
    "radii.safe_m": "d_safe: closer UAV pairs are penalised (m).",
    "signalling": "Sparse signalling (docs/SIGNALLING.md).",
    "signalling.tup_s": "T_up: every UAV broadcasts its state every this many seconds.",
    "signalling.buffer_len": "History length of the predictor's buffer (states).",
    "signalling.drop_after_missed": "A neighbour silent for this many signalling instants in a row leaves N_i.",
    "demand": "The user-density map the ground network publishes (docs/SIGNALLING.md, *Demand map*).",
    "demand.cell_m": "Cell side of the map (m); the area may have at most 65535 cells.",
    "demand.refresh_s": "The map is republished every this many seconds.",
    "timing": "The mission's clock.",
    "timing.dt_s": "The twin's physics step (s).",
    "timing.decision_every_s": "tau: the policy decides every this many seconds; the command is held between.",
    "timing.episode_s": "Mission length (s); `swarm up --duration` overrides it.",
    "reward": "Eq. (4)'s weights, before and after the first node failure (training only).",
    "reward.pre_failure": "Weights while every UAV is alive.",
    "reward.post_failure": "Weights once a UAV has failed (defaults 50, 2.0, 1e-5, 1.0; the rows below give "
                           "pre_failure's).",
    "reward.*.coverage": "w1: coverage C.",
    "reward.*.potential": "w2: closeness of the network centre to the users' centroid.",
    "reward.*.mobility": "w3: sum of squared speeds.",
    "reward.*.safety": "w4: separation penalty.",
    "launch": "Where the swarm starts: a line of `n_uavs` UAVs at take-off altitude.",
    "launch.north_m": "North of the line's centre (m): the line is centred on this point, not started at it.",
    "launch.east_m": "East of the line's centre (m).",
    "launch.spacing_m": "Distance between neighbours on the line (m).",
    "launch.bearing_deg": "Compass bearing from UAV 0 to UAV N-1 (90: west to east, UAV 0 westmost).",
    "origin": "Geodetic position of the mission frame's origin (GLOBAL_POSITION_INT, the autopilots' homes).",
    "origin.lat_deg": "Latitude (deg).",
    "origin.lon_deg": "Longitude (deg).",
    "origin.alt_m": "Altitude above mean sea level (m).",
    "failures": "Shorthand for `node_failure` events: `{at_s, uav}` each.",
    "failures[].at_s": "Mission second of the failure.",
    "failures[].uav": "Which UAV (0-based id) fails.",
    "events": "Scripted mission events on the sim clock (below: which fields each type takes).",
    "events[].type": "The event (see *Events*).",
    "events[].at_s": "Mission second it starts.",
    "events[].uav": "The one UAV it concerns (`node_failure`, `motor_failure`).",
    "events[].uavs": "The UAVs it concerns (empty: all).",
    "events[].duration_s": "How long it lasts (s); omitted: to the end where allowed.",
    "events[].tup_s": "`tup_change`: the new T_up (s).",
    "events[].std_m": "`gnss_noise`: standard deviation per axis (m).",
    "coordination": "How each agent gets its point of the plan (a policy that takes the plan, and `service`): `team`, the whole team's plan solved in every agent (model/service.py), or `local`, a plan of the agent's own neighbourhood (model/local_plan.py), whose cost per map does not grow with N or the area but which covers less (docs/RESULTS.md, *Session 13*).",
    "track_sensed_m": "Metres a UAV's plan point moves toward the centroid of the users it senses (model/sensed_track.py): it follows a moving crowd between demand maps, the team plan still deciding which crowd is whose. 0 (the default): the plan point. The same in every agent and in the twin (docs/RESULTS.md, *Session 19: moving demand*).",
    "transit_plan_m": "Metres from its plan point beyond which a learnt policy's UAV flies the plan follower's command (model/plan_follower.py), the motion every teammate's plan-aware prediction assumes when it declares a silent teammate failed or assigns a re-plan's points; within it the policy decides. 0 (the default): the policy everywhere. 300 (the station radius of the local failure repairs) is the value for long transits, a strip or a far launch: it covers more there and costs nothing measured elsewhere, but with it the learnt predictor no longer matters in transit. No effect on `service`, which always flies the plan follower's command (docs/RESULTS.md, *Session 28*).",
    "placement": "How the team plan places its points (`coordination: team`): `greedy`, each point where it serves the most still-unserved users of the map; `search`, that greedy from several first points, each plan improved by moving points locally, the best kept (model/placement.py); `learned`, a greedy whose picks a learnt scorer ranks (policies/pl-marl/placement.pt). The same in every agent and in the twin (docs/RESULTS.md, *Session 15*).",
    "failure_replan": "How a survivor's copy of the team plan changes when it learns that teammates failed (`coordination: team`): `resolve`, the whole plan solved again for the survivors; `local`, the first plan mended: each failed UAV's point is dropped and at most two of its own neighbours (the survivors within R_link of it in the first plan) move; the whole plan is solved again where no such repair keeps the swarm connected, and where the swarm is not yet on station (a survivor predicted more than 300 m from its point: a failure in transit; model/repairs.py). Under sparse signalling survivors learn failures at different instants; local repairs keep their copies' plans closer and gain after a 2-of-6 failure, and the station test keeps the re-solve in transit, where it wins. `local` is the default since session 27 (docs/RESULTS.md, *Session 27*).",
}

VEHICLE_DOCS: dict[str, str] = {
    "name": "The model's name.",
    "max_speed_mps": "V_max (m/s).",
    "max_accel_mps2": "A_max (m/s^2): the acceleration setpoint's bound.",
    "min_alt_m": "Lowest altitude of the mission band (m AGL).",
    "max_alt_m": "Highest altitude of the band (m AGL).",
    "takeoff_alt_m": "Take-off altitude, inside the band (m).",
    "max_climb_mps": "Climb rate during take-off (m/s).",
}

EVENT_DOCS = {
    "node_failure": "Vehicle `uav` stops (velocity zero), no longer covers or signals, and its agent is killed.",
    "link_blackout": "Links touching `uavs` (all when empty) are cut for `duration_s`.",
    "broker_outage": "The MQTT broker stops for `duration_s`, then restarts.",
    "tup_change": "The signalling interval becomes `tup_s`.",
    "gnss_noise": "Position telemetry of `uavs` gets Gaussian noise of `std_m` per axis, for `duration_s` "
                  "(to the end when omitted).",
    "gps_loss": "The GPS receiver of `uavs` goes dark for `duration_s` (to the end when omitted): the autopilot's "
                "own failsafe decides what follows.",
    "motor_failure": "One motor of vehicle `uav` stops for good: a quadrotor falls.",
}


def _type_text(tp: Any) -> str:
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin is Literal:
        return " \\| ".join(f"`{a}`" for a in args)
    if origin in (typing.Union, types.UnionType):
        inner = [a for a in args if a is not type(None)]
        return " or ".join(_type_text(a) for a in inner) + (", or omitted" if len(inner) < len(args) else "")
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            return f"list of {_type_text(args[0])}"
        return "[" + ", ".join(_type_text(a) for a in args) + "]"
    if dataclasses.is_dataclass(tp):
        return "mapping"
    return {int: "integer", float: "number", str: "string", bool: "true/false"}.get(tp, str(tp))


def _default_text(f: dataclasses.Field, parent_default: Any = None) -> str:
    if parent_default is not None:  # a nested mapping's default is its parent's default instance
        value = getattr(parent_default, f.name)
    elif f.default is not dataclasses.MISSING:
        value = f.default
    elif f.default_factory is not dataclasses.MISSING:
        value = f.default_factory()
    else:
        return "**required**"
    if dataclasses.is_dataclass(value):
        return "see below"
    if value == ():
        return "`[]`"
    if value is None:
        return "omitted"
    if isinstance(value, float) and value.is_integer() and abs(value) < 1e6:
        return f"`{value:g}`"
    return f"`{value}`"


def _bounds_text(f: dataclasses.Field) -> str:
    lo, hi = f.metadata.get("min"), f.metadata.get("max")
    return ", ".join(f"{op} {v:g}" if isinstance(v, float) else f"{op} {v}" for op, v in ((">=", lo), ("<=", hi)) if v is not None)


def _rows(cls: type, prefix: str, docs: dict[str, str], default: Any = None) -> list[tuple[str, str, str, str, str]]:
    rows = []
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        path = f"{prefix}{f.name}"
        tp = hints[f.name]
        doc = docs.get(path) or docs.get(path.replace("pre_failure.", "*.").replace("post_failure.", "*."))
        if doc is None:
            raise KeyError(f"{cls.__name__}.{f.name}: no line in FIELD_DOCS for {path!r}")
        rows.append((path, _type_text(tp), _default_text(f, default), _bounds_text(f), doc))
        item = typing.get_args(tp)[0] if typing.get_origin(tp) is tuple and typing.get_args(tp) else None
        if dataclasses.is_dataclass(tp) and not path.startswith("reward.post_failure"):
            sub = "reward.*." if path.startswith("reward.pre_failure") else f"{path}."
            own = getattr(default, f.name) if default is not None else (
                f.default if f.default is not dataclasses.MISSING else None)
            rows += _rows(tp, sub, docs, own)
        elif item is not None and dataclasses.is_dataclass(item):
            rows += _rows(item, f"{path}[].", docs)
    return rows


def _table(rows: list[tuple[str, str, str, str, str]]) -> list[str]:
    out = ["| key | type | default | bounds | meaning |", "|---|---|---|---|---|"]
    out += [f"| `{p}` | {t} | {d} | {b} | {m} |" for p, t, d, b, m in rows]
    return out


def render() -> str:
    """The whole reference, as docs/MISSIONS.md holds it."""
    events = [f"| `{name}` | {', '.join(f'`{x}`' for x in sorted(allowed)) or '-'} | "
              f"{', '.join(f'`{x}`' for x in sorted(required)) or '-'} | {EVENT_DOCS[name]} |"
              for name, (allowed, required) in _EVENT_FIELDS.items()]
    lines = [
        "# Mission reference",
        "",
        "<!-- Generated by `python -m plmarl_sitl.mission_reference` from the schema in plmarl_sitl/mission.py;",
        "     do not edit by hand (tests/test_mission_reference.py checks it is current). -->",
        "",
        "A mission is one YAML file that every part of the toolkit runs: the twin (`plmarl sim`, `eval`, `suite`,",
        "`train`) and the SITL swarm (`plmarl swarm up`). Units are SI. Positions are metres in the *mission frame*:",
        "origin at the area's south-west corner, x north, y east (altitude positive up where a key says `alt`).",
        "",
        "Loading is strict: an unknown key, a wrong type or a value out of bounds is one line naming its path",
        "(`failures[2].at_s: must be >= 0`) and exit 2; so are duplicate keys, non-UTF-8 bytes and files nested",
        "deeper than 32 levels. `extends: other.yaml` (relative to this file) starts from another mission: this",
        "file's keys override it, mappings merged key by key.",
        "",
        "```yaml",
        "extends: paper_urban.yaml          # the paper's Table I scenario",
        "name: my_site",
        "n_uavs: 5",
        "area: {north_m: 1000, east_m: 1500}",
        "users: {count: 300, cluster_size: 60, layout: fixed,",
        "        cluster_centers: [[300, 300], [550, 450], [400, 700], [650, 900], [500, 1150]]}",
        "launch: {north_m: 100, east_m: 750, spacing_m: 40, bearing_deg: 90}   # the centre of the line",
        "events:",
        "  - {type: node_failure, at_s: 100, uav: 2}",
        "```",
        "",
        "## Keys",
        "",
        *_table(_rows(Mission, "", FIELD_DOCS)),
        "",
        "## Events",
        "",
        "Each entry of `events` has a `type` and `at_s`, and only the fields its type takes:",
        "",
        "| type | takes | requires | what happens |",
        "|---|---|---|---|",
        *events,
        "",
        "## Vehicle models",
        "",
        "`vehicle:` names a file in `vehicle_models/` (`quadrotor`) or is a path to a YAML file of your own",
        "(with a suffix, e.g. `vehicle: ./my_hexa.yaml`, relative to the working directory). A policy refuses a",
        "mission whose vehicle limits differ from the ones it was trained with.",
        "",
        *_table(_rows(VehicleModel, "", VEHICLE_DOCS)),
        "",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Write docs/MISSIONS.md (or, with --check, exit 1 if it is not current)."""
    ap = argparse.ArgumentParser(prog="python -m plmarl_sitl.mission_reference",
                                 description=f"Write the mission YAML reference ({OUT.name}) from the mission schema "
                                 "and the descriptions in this module.")
    ap.add_argument("--check", action="store_true", help="write nothing; exit 1 if the file is not current")
    args = ap.parse_args(sys.argv[1:] if argv is None else argv)
    text = render()
    if args.check:
        current = OUT.read_text() if OUT.exists() else ""
        if current != text:
            print(f"{OUT} is not current: run python -m plmarl_sitl.mission_reference", file=sys.stderr)
            return 1
        return 0
    Path(OUT).write_text(text)
    print(f"wrote {OUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
