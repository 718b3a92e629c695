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
import json
import logging
import signal
import sys
from pathlib import Path

from plmarl_sitl.cmdline import add_seed, speedup_arg, swarm_name_arg
from plmarl_sitl.errors import UserError
from plmarl_sitl.sitl.lockstep import DEFAULT_STARTUP_SPEEDUP, DEFAULT_STRAGGLER_S, speedup_or_default

EPILOG = """\
examples:
  plmarl world missions/paper_urban.yaml --broker mqtt://127.0.0.1:1883 --swarm-key swarm.key --speedup 10
  plmarl world missions/paper_urban.yaml --broker mqtt://127.0.0.1:18830 --embedded-broker --no-auth --episode 200
then one agent per vehicle, with the same key:
  plmarl agent --id 0 --connect udpout://127.0.0.1:14540 --broker mqtt://127.0.0.1:1883 --swarm-key swarm.key
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
    p.add_argument("--swarm", type=swarm_name_arg, default="sitl", help="swarm name in the topic tree plmarl/<swarm>/... (default sitl)")
    p.add_argument("--external", default=None, metavar="URL[,URL...]",
                   help="vehicles that run elsewhere, one MAVLink URL per UAV in order (tcpout://HOST:PORT, "
                   "udpin://BIND:PORT, udpout://HOST:PORT): no emulated autopilots; positions, modes and clocks "
                   "from these links (a link of the world's own: ArduPilot SITL SERIAL1, a MAVLink router output)")
    p.add_argument("--personality", choices=["px4", "ardupilot"], default="px4")
    p.add_argument("--boot", choices=["instant", "real"], default="instant",
                   help="autopilot start-up: instant (home and position at once, default) or real "
                   "(ArduCopter's measured timeline: home after ~19 s, position after ~40 s of sim time)")
    p.add_argument("--speedup", type=speedup_arg, default=None, help="sim seconds per wall second (default 1; with --lockstep: "
                   f"the pace of the start-up only, default {DEFAULT_STARTUP_SPEEDUP:g})")
    p.add_argument("--lockstep", action="store_true",
                   help="lockstep: vehicle time waits for every agent's answer to each telemetry sample (agents run with "
                        "--lockstep), as fast as they compute; same mission and seed, same outputs (emulated vehicles only)")
    p.add_argument("--straggler", type=float, default=DEFAULT_STRAGGLER_S, metavar="S",
                   help=f"with --lockstep: an agent that owes an answer for S wall seconds is declared failed and its "
                        f"vehicle left to its failsafe (default {DEFAULT_STRAGGLER_S:g})")
    p.add_argument("--mavlink-keys", type=Path, default=None, metavar="DIR",
                   help="MAVLink 2 signing: vehicle i signs with DIR/vehicleI.key (0600; `plmarl swarm up` writes them "
                   "to RUN/mavlink) and drops unsigned commands and setpoints; with --external the world's links sign "
                   "with them (default: unsigned)")
    p.add_argument("--base-port", type=int, default=14540, help="UDP port of vehicle 0 (default 14540)")
    p.add_argument("--n-uavs", type=int, default=None, help="override the mission's number of UAVs")
    p.add_argument("--loss", type=float, default=0.0, help="extra per-delivery loss probability (default 0)")
    p.add_argument("--latency", type=float, default=0.0, metavar="S", help="delivery latency, sim seconds (default 0)")
    p.add_argument("--episode", type=int, default=None, metavar="S",
                   help="stop after S mission seconds and print the mean coverage (default: run until Ctrl-C)")
    p.add_argument("--summary-json", default=None, metavar="PATH", help="write the run summary (coverage trace) here")
    p.add_argument("-v", "--verbose", action="store_true")
    add_seed(p, default=None)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from plmarl_sitl.mission import load_mission
    from plmarl_sitl.sitl.autopilot.boot import check_boot

    args.speedup = speedup_or_default(args.speedup, args.lockstep)
    if not args.speedup > 0:
        raise UserError("--speedup must be > 0")
    check_boot(args.personality, args.boot)
    if not 0 <= args.loss <= 1:
        raise UserError("--loss must be in [0, 1]")
    if args.lockstep and args.external:
        raise UserError("--lockstep needs the emulated vehicles (external autopilots run clocks of their own)")
    if not args.straggler > 0:
        raise UserError("--straggler must be > 0 s")
    from plmarl_sitl.deploy.mqtt.auth import key_from_flags
    from plmarl_sitl.deploy.mqtt.credentials import load_credentials

    args.key = key_from_flags(args.swarm_key, args.no_auth)
    args.credentials = load_credentials(args.broker_credentials) if args.broker_credentials else None
    mission = load_mission(args.mission)
    if args.mavlink_keys is not None:
        from plmarl_sitl.deploy.mavlink.keys import load_key_files

        args.mavlink_keys = load_key_files(args.mavlink_keys, args.n_uavs or mission.n_uavs, "--mavlink-keys")
    args.external = _external_urls(args.external)
    if args.external:
        n = args.n_uavs or mission.n_uavs
        if len(args.external) != n:
            raise UserError(f"--external: {len(args.external)} URL(s) for {n} UAVs (one per UAV; or set --n-uavs)")
        from plmarl_sitl.deploy.mavlink.connect import parse_url

        for url in args.external:
            parse_url(url)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(asctime)s %(name)s %(levelname)s %(message)s", stream=sys.stderr)
    return asyncio.run(_main(args, mission))


def _external_urls(text: str | None) -> tuple[str, ...]:
    if text is None:
        return ()
    urls = tuple(u.strip() for u in text.split(",") if u.strip())
    if not urls:
        raise UserError("--external: expected URL[,URL...]")
    return urls


async def _main(args: argparse.Namespace, mission) -> int:  # noqa: ANN001
    from plmarl_sitl.deploy.mqtt.url import parse_broker_url
    from plmarl_sitl.sitl.network.broker import EmbeddedBroker
    from plmarl_sitl.sitl.world import SitlWorld, WorldConfig

    cfg = WorldConfig(
        mission=mission,
        broker_url=args.broker,
        swarm=args.swarm,
        personality=args.personality,
        boot=args.boot,
        speedup=args.speedup,
        base_port=args.base_port,
        seed=args.seed,
        loss=args.loss,
        latency_s=args.latency,
        episode_s=args.episode,
        n_uavs=args.n_uavs,
        external=args.external,
        swarm_key=args.key,
        broker_credentials=args.credentials,
        mavlink_keys=tuple(args.mavlink_keys or ()),
        lockstep=args.lockstep,
        straggler_s=args.straggler,
    )
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
        raise UserError(f"cannot bind UDP ports from {args.base_port}: {exc.strerror}") from exc
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, world.stop)
    if world.host is not None:
        ports = world.host.ports
        vehicles = f"{world.n} {args.personality} vehicle(s) on udp 127.0.0.1:{ports[0]}-{ports[-1]}"
    else:
        vehicles = f"{world.n} external vehicle(s) on {', '.join(args.external)} (waiting for their telemetry)"
    print(
        f"plmarl world: {vehicles}, broker {args.broker}{' (embedded)' if broker else ''}, swarm {args.swarm!r}, "
        f"speedup {args.speedup:g}" + (f", lockstep (an agent silent for {args.straggler:g} s wall is declared failed)"
                                       if args.lockstep else ""),
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
