"""`plmarl autopilot`: N point-mass autopilots speaking MAVLink 2 over UDP, like PX4 SITL.

Vehicle i listens on 127.0.0.1:(base_port + i) with sysid i + 1 and answers whoever sends
to it, so clients connect with `udpout://127.0.0.1:PORT` (MAVSDK) or `udpout:...`
(pymavlink/MAVProxy). Ctrl-C (or SIGTERM) stops it cleanly and prints the input counters.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import signal
import sys

from plmarl_sitl.cmdline import speedup_arg
from plmarl_sitl.deploy.mavlink.personality import PERSONALITIES
from plmarl_sitl.errors import UserError
from plmarl_sitl.mission import Origin

EPILOG = """\
examples:
  plmarl autopilot --count 4
  plmarl autopilot --count 20 --personality ardupilot --speedup 10 --gcs udp:127.0.0.1:14550
  plmarl autopilot --count 1 --signing-key $(python -c 'print("ab"*32)')
then e.g.:  mavproxy.py --master udpout:127.0.0.1:14540"""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "autopilot",
        help="run N emulated PX4/ArduPilot autopilots (MAVLink 2 over UDP)",
        description=__doc__.split("\n\n")[1].replace("\n", " "),
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--count", type=int, default=1, help="number of vehicles (default 1)")
    p.add_argument("--base-port", type=int, default=14540, help="UDP port of vehicle 0 (default 14540)")
    p.add_argument("--bind", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    # Not argparse choices: an unknown name is one error line (UserError), like every bad flag.
    p.add_argument("--personality", default="px4", metavar="NAME",
                   help=f"autopilot to emulate: {', '.join(PERSONALITIES)} (default px4)")
    p.add_argument("--vehicle", default="quadrotor", help="vehicle model name or YAML path (default quadrotor)")
    p.add_argument("--home", default=None, metavar="LAT,LON,ALT", help="geodetic origin of the mission frame")
    p.add_argument("--spacing", type=float, default=5.0, metavar="M",
                   help="vehicle i's home is i*M metres east of the origin (default 5)")
    p.add_argument("--speedup", type=speedup_arg, default=1.0, help="sim seconds per wall second (default 1)")
    p.add_argument("--boot", choices=["instant", "real"], default="instant",
                   help="autopilot start-up: instant (home and position at once, default) or real "
                   "(ArduCopter's measured timeline: home after ~19 s, position after ~40 s of sim time); "
                   "with real, the clock starts at the first datagram, as ArduPilot's SITL waits for its client)")
    p.add_argument("--signing-key", default=None, metavar="HEX", help="MAVLink 2 signing key, 64 hex digits")
    p.add_argument("--gcs", default=None, metavar="udp:HOST:PORT", help="also push telemetry to this ground station")
    p.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S wall seconds")
    p.add_argument("-v", "--verbose", action="store_true", help="log every state change")
    p.set_defaults(func=run)


def parse_home(text: str) -> Origin:
    try:
        lat, lon, alt = (float(x) for x in text.split(","))
        return Origin(lat, lon, alt)
    except ValueError:
        raise UserError(f"--home: expected LAT,LON,ALT (three numbers), got {text!r}") from None


def parse_gcs(text: str) -> tuple[str, int]:
    parts = text.split(":")
    if len(parts) != 3 or parts[0] != "udp" or not parts[2].isdigit():
        raise UserError(f"--gcs: expected udp:HOST:PORT, got {text!r}")
    return parts[1], int(parts[2])


def parse_key(text: str) -> bytes:
    try:
        key = bytes.fromhex(text)
    except ValueError:
        key = b""
    if len(key) != 32:
        raise UserError("--signing-key: expected 64 hex digits (a 32-byte key)")
    return key


def run(args: argparse.Namespace) -> int:
    from plmarl_sitl.sitl.autopilot.boot import check_boot

    check_boot(args.personality, args.boot)  # an unknown name fails here, before anything starts
    if not 1 <= args.count <= 250:
        raise UserError("--count must be in 1..250 (one MAVLink system id per vehicle)")
    if not args.speedup > 0:
        raise UserError("--speedup must be > 0")
    if not 1 <= args.base_port <= 65535 - args.count + 1:
        raise UserError("--base-port: the port range does not fit below 65536")
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    return asyncio.run(_main(args))


async def _main(args: argparse.Namespace) -> int:
    from plmarl_sitl.sitl.autopilot import AutopilotHost, run_realtime

    host = AutopilotHost(
        args.count,
        personality_name=args.personality,
        vehicle=args.vehicle,
        origin=parse_home(args.home) if args.home else None,
        home_offsets_ned=[(0.0, i * args.spacing, 0.0) for i in range(args.count)],
        base_port=args.base_port,
        bind_host=args.bind,
        signing_key=parse_key(args.signing_key) if args.signing_key else None,
        gcs=parse_gcs(args.gcs) if args.gcs else None,
        boot=args.boot,
    )
    try:
        await host.start()
    except OSError as exc:
        raise UserError(f"cannot bind UDP ports {host.ports[0]}-{host.ports[-1]}: {exc.strerror}") from exc
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    print(
        f"plmarl autopilot: {args.count} {args.personality} vehicle(s) on udp {args.bind}:"
        f"{host.ports[0]}-{host.ports[-1]} (sysid 1-{args.count}), speedup {args.speedup:g}, boot {args.boot}; "
        "Ctrl-C stops",
        flush=True,
    )
    try:
        if args.boot == "real":
            # ArduPilot's SITL starts its clock when its client connects, so the client sees
            # the whole start-up (STATUSTEXTs included): do the same.
            while not stop.is_set() and not any(v.peers for v in host.vehicles):
                await asyncio.sleep(0.005)
        stats = await run_realtime(host, args.speedup, stop=stop, duration_s=args.duration)
    finally:
        host.close()
    dropped = [(v.sysid, v.counters) for v in host.vehicles if v.counters.dropped]
    print(
        f"plmarl autopilot: stopped after {stats.wall_s:.1f} s wall, {stats.sim_s:.1f} s sim "
        f"(x{stats.realtime_factor:.2f}); bad input: "
        + ("; ".join(f"sysid {s}: {c.summary()}" for s, c in dropped) if dropped else "none"),
        file=sys.stderr,
    )
    return 0
