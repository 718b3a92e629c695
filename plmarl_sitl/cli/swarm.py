"""`plmarl swarm up|status`: launch a SITL swarm mission, or watch a running one."""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
from pathlib import Path

from plmarl_sitl.sitl.fork_protocol import THREADS_ENV

# `swarm up` forks its agents' server from this process (sitl/forked.py), which must then run
# one thread: one BLAS/OpenMP thread, as every agent has, set before numpy loads (just below),
# or OpenBLAS starts a second one.
for _name, _value in THREADS_ENV.items():
    os.environ.setdefault(_name, _value)

from plmarl_sitl.cmdline import add_flags, from_flags, swarm_name_arg  # noqa: E402
from plmarl_sitl.sitl.options import SwarmOptions, UpOptions  # noqa: E402

SWARM_FIELDS = [f.name for f in dataclasses.fields(SwarmOptions)]  # flags of their own group

UP_EPILOG = """\
examples:
  plmarl swarm up missions/paper_urban.yaml --speedup 10
  plmarl swarm up missions/node_failure.yaml --speedup 10 --headless --out runs/failure
  plmarl swarm up missions/scale_20.yaml --lockstep --headless    # deterministic, as fast as the agents compute
  plmarl swarm up missions/paper_urban.yaml --policy service --lockstep --headless    # the plan follower, not learnt
  plmarl swarm up missions/broker_outage.yaml --broker mqtt://127.0.0.1:1883 --headless
  plmarl swarm up missions/paper_urban.yaml --autopilot arducopter=$HOME/ardupilot/build/sitl/bin/arducopter \\
      --speedup 5 --headless    # one real ArduCopter SITL per UAV
  plmarl swarm up missions/node_failure.yaml --autopilot px4=$HOME/PX4-Autopilot/build/px4_sitl_default \\
      --speedup 2 --headless    # one real PX4 SITL (SIH quadrotor) per UAV
  plmarl swarm up missions/paper_urban.yaml --hosts hosts.yaml --broker mosquitto --lockstep --headless
      # agents on companion computers reached by ssh; hosts.yaml:
      #   launcher: {address: 10.0.0.1}      # the broker and the vehicles' UDP ports listen here
      #   hosts:
      #     - {name: cc-a, run: [ssh, -o, BatchMode=yes, pi@10.0.0.2], address: 10.0.0.2, uavs: [0, 1]}
      #     - {name: cc-b, run: [ssh, -o, BatchMode=yes, pi@10.0.0.3], address: 10.0.0.3, uavs: [2, 3]}

The mission clock starts once every vehicle is airborne under its agent. Ctrl-C stops
everything cleanly. Afterwards: plmarl report RUN_DIR draws the plots."""


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("swarm", help="launch a SITL swarm mission, or watch a running one",
                       description="Launch a whole software-in-the-loop swarm, or attach to one.")
    ssub = p.add_subparsers(dest="swarm_command", metavar="SUBCOMMAND", required=True)

    up = ssub.add_parser(
        "up",
        help="broker + SITL world + one agent per UAV, run the mission, record it",
        description="Start the MQTT broker (embedded amqtt, or an external one), the SITL world "
        "(emulated PX4/ArduPilot autopilots, ground users, link emulator) and one `plmarl agent` "
        "per UAV; wait until every vehicle is airborne; run the mission with its scripted events "
        "(node_failure, link_blackout, broker_outage, tup_change, gnss_noise, gps_loss, motor_failure); show the live view; "
        "record .tlogs, metrics.jsonl, events.jsonl, mission.yaml and summary.json; shut down.",
        epilog=UP_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_flags(up, UpOptions, skip=SWARM_FIELDS)
    add_flags(up.add_argument_group("the vehicles and their clock (as in `plmarl world`)"), SwarmOptions)
    up.add_argument("--json", action="store_true", help="print the summary as one JSON object at the end")
    up.set_defaults(func=run_up)

    st = ssub.add_parser(
        "status",
        help="attach the live view to a running swarm",
        description="Subscribe to a running swarm's metrics and signalling topics and show the live "
        "status view (refreshed 4 times a second; Ctrl-C to leave).",
        epilog="example:\n  plmarl swarm status --broker mqtt://127.0.0.1:1883 --swarm sitl",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    st.add_argument("--broker", required=True, metavar="mqtt://HOST:PORT", help="the swarm's broker")
    st.add_argument("--swarm", type=swarm_name_arg, default="sitl", help="swarm name (default sitl)")
    st.add_argument("--swarm-key", default=None, metavar="FILE",
                    help="the swarm's key file: without it the view shows metrics but no signed signalling")
    st.add_argument("--broker-credentials", default=None, metavar="FILE",
                    help="the view's broker login, one line USERNAME:PASSWORD (a SITL run writes credentials/view.cred)")
    st.set_defaults(func=run_status)

    kg = ssub.add_parser("keygen", help="write a fresh random swarm key file (mode 0600)",
                         description="Write a fresh random 32-byte swarm key, as 64 hexadecimal characters, to FILE "
                         "with owner-only permissions; give the same file to the world and every agent (--swarm-key).")
    kg.add_argument("file", type=Path, help="the key file to create (must not exist)")
    kg.set_defaults(func=run_keygen)


def run_up(args: argparse.Namespace) -> int:
    from plmarl_sitl.mission import load_mission
    from plmarl_sitl.sitl import forked

    # The flags and the mission first (plain Python the agents import anyway): a mistake in
    # either is one line at once, not after torch's import (~2-4 s).
    opts = from_flags(UpOptions, args, headless=args.headless or args.json)
    mission = load_mission(opts.mission_path)
    # Then, before the world's imports and any thread: import torch once and fork the agents'
    # server from this process, which imports the agents' modules on the other core meanwhile
    # (issue 25.1: the rig imported torch twice, once here and once in an exec'd forkserver).
    forked.start_server()
    try:
        from plmarl_sitl.sitl.launcher import ComponentFailed
        from plmarl_sitl.sitl.launcher import run_up as launch

        try:
            summary = launch(opts, mission)
        except ComponentFailed as exc:
            print(f"plmarl swarm up: failed: {exc.reason}", file=sys.stderr)
            return 1
    finally:
        forked.stop_server()
    if args.json:
        print(json.dumps(summary))
        return 0
    from rich.console import Console

    from plmarl_sitl.sitl.report import print_summary

    print_summary(summary, Console(), title=f"run {summary['run_dir']}")
    return 0


def run_status(args: argparse.Namespace) -> int:
    from plmarl_sitl.deploy.mqtt.auth import load_key
    from plmarl_sitl.deploy.mqtt.credentials import load_credentials
    from plmarl_sitl.sitl.launcher import status

    key = load_key(args.swarm_key) if args.swarm_key else None
    credentials = load_credentials(args.broker_credentials) if args.broker_credentials else None
    status(args.broker, args.swarm, key=key, credentials=credentials)
    return 0


def run_keygen(args: argparse.Namespace) -> int:
    from plmarl_sitl.deploy.mqtt.auth import create_key_file
    from plmarl_sitl.errors import UserError

    if args.file.exists():
        raise UserError(f"{args.file} exists: a key is not overwritten (remove it first to rotate)")
    if not args.file.parent.is_dir():
        raise UserError(f"{args.file}: no such directory {args.file.parent}")
    key = create_key_file(args.file)
    print(f"wrote {args.file} (key id {key.key_id:#04x}, mode 600)")
    return 0
