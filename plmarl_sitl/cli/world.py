"""`plmarl world MISSION --broker URL`: the SITL world process on its own.

Hosts N emulated autopilots (vehicle i on udp 127.0.0.1:base_port + i, home at the
twin's launch position i on the ground), the ground users, the link emulator and the
swarm metrics, all on one clock (--speedup); or, with --external, runs the mission on
vehicles that already fly elsewhere (one MAVLink URL each), following their clocks.
Agents connect with `plmarl agent --id I --connect udpout://127.0.0.1:PORT --broker URL`.
"""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import json
import logging
import signal
import sys
from pathlib import Path
from typing import TYPE_CHECKING

from plmarl_sitl.cmdline import add_flags, from_flags
from plmarl_sitl.errors import UserError
from plmarl_sitl.sitl.options import SwarmOptions, WorldOptions

if TYPE_CHECKING:
    from plmarl_sitl.sitl.world import WorldConfig

SWARM_FIELDS = [f.name for f in dataclasses.fields(SwarmOptions)]  # flags of their own group

EPILOG = """\
examples:
  plmarl world missions/paper_urban.yaml --broker mqtt://127.0.0.1:1883 --swarm-key swarm.key --speedup 10
  plmarl world missions/paper_urban.yaml --broker mqtt://127.0.0.1:18830 --embedded-broker --no-auth --episode 200
then one agent per vehicle, with the same key:
  plmarl agent --id 0 --connect udpout://127.0.0.1:14540 --broker mqtt://127.0.0.1:1883 --swarm-key swarm.key
in lockstep (deterministic, as fast as the agents compute; each agent with --lockstep too):
  plmarl world missions/paper_urban.yaml --broker mqtt://127.0.0.1:1883 --swarm-key swarm.key --lockstep --episode 200
vehicles that run elsewhere (each flown by its own agent; here two ArduCopter SITLs, SERIAL1):
  plmarl world missions/paper_urban.yaml --n-uavs 2 --broker mqtt://127.0.0.1:1883 --swarm-key swarm.key \\
      --external tcpout://127.0.0.1:5762,tcpout://127.0.0.1:5772 --speedup 5
a key file (0600): plmarl swarm keygen swarm.key"""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "world",
        help="SITL world: emulated autopilots, ground users, link emulator, metrics",
        description=__doc__.split("\n\n")[1].replace("\n", " "),
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("mission", help="mission YAML (e.g. missions/paper_urban.yaml)")
    p.add_argument("--broker", required=True, metavar="URL", help="MQTT broker, mqtt://HOST:PORT")
    p.add_argument("--broker-credentials", default=None, metavar="FILE",
                   help="the world's broker login: one line USERNAME:PASSWORD, mode 0600 (default: anonymous)")
    a = p.add_mutually_exclusive_group()
    a.add_argument("--swarm-key", default=None, metavar="FILE",
                   help="the swarm key (64 hex characters, mode 0600): relay only authentic states, sign start, ctl, "
                   "closed, sensing and demand (docs/SECURITY.md). Required unless --no-auth")
    a.add_argument("--no-auth", action="store_true", help="unsigned version-1 messages (anyone on the broker can steer)")
    p.add_argument("--embedded-broker", action="store_true", help="host an amqtt broker in this process on the --broker port")
    p.add_argument("--mavlink-keys", type=Path, default=None, metavar="DIR",
                   help="MAVLink 2 signing: vehicle i signs with DIR/vehicleI.key (0600; `plmarl swarm up` writes them "
                   "to RUN/mavlink) and drops unsigned commands and setpoints; with --external the world's links sign "
                   "with them (default: unsigned)")
    p.add_argument("--summary-json", default=None, metavar="PATH", help="write the run summary (coverage trace) here")
    p.add_argument("-v", "--verbose", action="store_true", help="log the world's progress (start-up, events) on stderr")
    add_flags(p.add_argument_group("the world"), WorldOptions, skip=SWARM_FIELDS)
    add_flags(p.add_argument_group("the vehicles and their clock (as in `plmarl swarm up`)"), SwarmOptions)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from plmarl_sitl.deploy.mqtt.auth import key_from_flags
    from plmarl_sitl.deploy.mqtt.credentials import load_credentials
    from plmarl_sitl.mission import load_mission
    from plmarl_sitl.sitl.world import WorldConfig

    key = key_from_flags(args.swarm_key, args.no_auth)
    credentials = load_credentials(args.broker_credentials) if args.broker_credentials else None
    mission = load_mission(args.mission)
    mavlink_keys: list[bytes] = []
    if args.mavlink_keys is not None:
        from plmarl_sitl.deploy.mavlink.keys import load_key_files

        mavlink_keys = load_key_files(args.mavlink_keys, args.n_uavs or mission.n_uavs, "--mavlink-keys")
    cfg = from_flags(WorldConfig, args, mission=mission, broker_url=args.broker, swarm_key=key,
                     broker_credentials=credentials, mavlink_keys=tuple(mavlink_keys))
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(asctime)s %(name)s %(levelname)s %(message)s", stream=sys.stderr)
    return asyncio.run(_main(args, cfg))


async def _main(args: argparse.Namespace, cfg: WorldConfig) -> int:
    from plmarl_sitl.deploy.mqtt.url import parse_broker_url
    from plmarl_sitl.sitl.network.broker import EmbeddedBroker
    from plmarl_sitl.sitl.world import SitlWorld

    broker = None
    if args.embedded_broker:
        host, port = parse_broker_url(args.broker)
        broker = EmbeddedBroker(host, port)
        await broker.start()
    world = SitlWorld(cfg)
    try:
        await world.start()
    except OSError as exc:
        if broker is not None:
            await broker.stop()
        raise UserError(f"cannot bind UDP ports from {cfg.base_port}: {exc.strerror}") from exc
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, world.stop)
    if world.host is not None:
        ports = world.host.ports
        vehicles = f"{world.n} {cfg.personality} vehicle(s) on udp 127.0.0.1:{ports[0]}-{ports[-1]}"
    else:
        vehicles = f"{world.n} external vehicle(s) on {', '.join(cfg.external)} (waiting for their telemetry)"
    print(
        f"plmarl world: {vehicles}, broker {args.broker}{' (embedded)' if broker else ''}, swarm {cfg.swarm!r}, "
        f"speedup {cfg.speedup:g}" + (f", lockstep (an agent silent for {cfg.straggler_s:g} s wall is declared failed)"
                                      if cfg.lockstep else ""),
        flush=True,
    )
    try:
        summary = await world.run()
    finally:
        if broker is not None:
            await broker.stop()
    out = {
        "t0_boot_s": summary.t0_boot_s,
        "mission_seconds": len(summary.coverage),
        "mean_coverage": summary.mean_coverage if summary.coverage else None,
        "mean_lambda2": sum(summary.lambda2) / len(summary.lambda2) if summary.lambda2 else None,
        "wall_s": summary.wall_s,
        "sim_s": summary.sim_s,
        "links": summary.links,
        "coverage": summary.coverage,
    }
    if args.summary_json:
        with open(args.summary_json, "w") as f:
            json.dump(out, f)
    print(
        f"plmarl world: stopped after {summary.sim_s:.1f} s sim ({summary.wall_s:.1f} s wall); "
        f"{len(summary.coverage)} mission seconds, mean coverage "
        + (f"{summary.mean_coverage:.4f}" if summary.coverage else "n/a"),
        flush=True,
    )
    return 0
