"""`plmarl swarm up|status`: launch a SITL swarm mission, or watch a running one."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from plmarl_sitl.cmdline import add_seed, speedup_arg, swarm_name_arg
from plmarl_sitl.sitl.lockstep import DEFAULT_STARTUP_SPEEDUP, DEFAULT_STRAGGLER_S, speedup_or_default

UP_EPILOG = """\
examples:
  plmarl swarm up missions/paper_urban.yaml --speedup 10
  plmarl swarm up missions/node_failure.yaml --speedup 10 --headless --out runs/failure
  plmarl swarm up missions/scale_20.yaml --lockstep --headless    # deterministic, as fast as the agents compute
  plmarl swarm up missions/paper_urban.yaml --policy service --lockstep --headless    # the plan follower, not learnt
  plmarl swarm up missions/broker_outage.yaml --broker mqtt://127.0.0.1:1883 --headless
  plmarl swarm up missions/paper_urban.yaml --autopilot arducopter=$HOME/ardupilot/build/sitl/bin/arducopter \\
      --speedup 5 --headless    # one real ArduCopter SITL per UAV
  plmarl swarm up missions/node_failure.yaml --autopilot px4=$HOME/PX4-Autopilot/build/px4_sitl_default \
      --speedup 2 --headless    # one real PX4 SITL (SIH quadrotor) per UAV
  plmarl swarm up missions/paper_urban.yaml --hosts hosts.yaml --broker mosquitto --lockstep --headless
      # agents on companion computers reached by ssh; hosts.yaml:
      #   launcher: {address: 10.0.0.1}      # the broker and the vehicles' UDP ports listen here
      #   hosts:
      #     - {name: cc-a, run: [ssh, -o, BatchMode=yes, pi@10.0.0.2], address: 10.0.0.2, uavs: [0, 1]}
      #     - {name: cc-b, run: [ssh, -o, BatchMode=yes, pi@10.0.0.3], address: 10.0.0.3, uavs: [2, 3]}

The mission clock starts once every vehicle is airborne under its agent. Ctrl-C stops
everything cleanly. Afterwards: plmarl report RUN_DIR draws the plots."""


def policy_arg(text: str) -> Path:
    """A policy directory; a bare name that is not one (e.g. `service`) is the project's policies/NAME."""
    from plmarl_sitl.config import PROJECT_POLICIES

    path = Path(text)
    if not path.is_dir() and len(path.parts) == 1 and (PROJECT_POLICIES / text).is_dir():
        return PROJECT_POLICIES / text
    return path


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
    up.add_argument("mission", type=Path, help="mission YAML, e.g. missions/paper_urban.yaml")
    up.add_argument("--speedup", type=speedup_arg, default=None, help="sim seconds per wall second (default 1, real time; "
                    f"with --lockstep: the pace of the start-up only, default {DEFAULT_STARTUP_SPEEDUP:g})")
    up.add_argument("--lockstep", action="store_true",
                    help="lockstep SITL: vehicle time waits for every agent's answer to each telemetry sample, so the run "
                         "is as fast as the agents compute, never late, and the same mission and seed give the same "
                         "metrics.jsonl, events.jsonl and summary (emulated autopilots only)")
    up.add_argument("--straggler", type=float, default=DEFAULT_STRAGGLER_S, metavar="S",
                    help=f"with --lockstep: an agent that owes an answer for S wall seconds is declared failed, killed, and "
                         f"its vehicle left to its failsafe; the mission goes on (default {DEFAULT_STRAGGLER_S:g})")
    up.add_argument("--duration", type=int, default=None, metavar="S", help="mission seconds to fly (default: the mission's episode length)")
    up.add_argument("--broker", default="embedded", metavar="embedded|mosquitto|mqtt://HOST:PORT",
                    help="MQTT broker: embedded (amqtt in a child process, default), mosquitto (a mosquitto child), both "
                    "with a login per process and an ACL; or an external broker by URL (its access control is its own)")
    up.add_argument("--headless", action="store_true", help="no live view: one status line every 10 s of sim time")
    up.add_argument("--out", type=Path, default=None, metavar="DIR", help="run directory (default runs/<timestamp>)")
    add_seed(up, default=None)
    up.add_argument("--policy", type=policy_arg, default=None, metavar="DIR|NAME",
                    help="policy directory, or the name of one of the project's (policies/NAME: pl-marl, gru, tag-mappo, "
                    "or service, the plan follower, not learnt); default policies/pl-marl")
    up.add_argument("--autopilot", type=autopilot_arg, default=("emulator", None), metavar="emulator|arducopter=PATH|px4=PATH",
                    help="the autopilots: emulator (the point-mass emulator in the world's process, default), "
                    "arducopter=PATH (one real ArduCopter SITL process per UAV, PATH the `arducopter` binary built from "
                    "ArduPilot's source; its home at the mission's launch slot, its clock sped up by --speedup) or "
                    "px4=PATH (one real PX4 SITL process with its SIH quadrotor per UAV, PATH PX4's build output "
                    "build/px4_sitl_default; home at the launch slot, PX4_SIM_SPEED_FACTOR = --speedup; unsigned: "
                    "PX4 has no MAVLink signing)")
    up.add_argument("--copter-parm", type=Path, default=None, metavar="FILE",
                    help="with arducopter: ArduPilot's copter.parm (default: Tools/autotest/default_params/copter.parm "
                    "in the ArduPilot tree the binary was built in)")
    up.add_argument("--instance", type=int, default=None, metavar="I",
                    help="with arducopter: UAV i runs as ArduPilot SITL instance -I I+i, ports 5760 + 10 (I+i); "
                    "with px4: as PX4 instance -i I+i (at most 9), udp 18570 + I+i (world) and 14540 + I+i (agent) "
                    "(default: the first instances whose ports are free)")
    up.add_argument("--personality", choices=["px4", "ardupilot"], default="px4",
                    help="with the emulator: autopilot personality (default px4)")
    up.add_argument("--boot", choices=["instant", "real"], default="instant",
                    help="autopilot start-up: instant (home and position at once, default) or real "
                   "(ArduCopter's measured timeline: home after ~19 s, position after ~40 s of sim time)")
    up.add_argument("--swarm-name", type=swarm_name_arg, default="sitl", help="MQTT topic namespace plmarl/<name>/... (default sitl)")
    up.add_argument("--broker-credentials", type=Path, default=None, metavar="DIR",
                    help="with an external broker: the logins it knows this swarm by, DIR/world.cred, DIR/monitor.cred "
                    "and DIR/agentI.cred (one line USERNAME:PASSWORD each, mode 0600)")
    a = up.add_mutually_exclusive_group()
    a.add_argument("--swarm-key", type=Path, default=None, metavar="FILE",
                   help="sign every message with this key file (64 hex characters, mode 0600; default: a fresh key "
                   "in the run directory, swarm.key)")
    a.add_argument("--no-auth", action="store_true",
                   help="fly with unsigned messages (anyone who can publish on the broker can steer the swarm)")
    up.add_argument("--mavlink-sign", action=argparse.BooleanOptionalAction, default=True,
                    help="MAVLink 2 signing between each autopilot and its agent, and on the world's links (default on: "
                    "a fresh key per vehicle in RUN_DIR/mavlink/vehicleI.key, 0600; a real ArduCopter gets it by "
                    "SETUP_SIGNING). Unsigned or badly signed commands and setpoints are then dropped and counted")
    up.add_argument("--mavlink-keys", type=Path, default=None, metavar="DIR",
                    help="with --mavlink-sign: use DIR/vehicleI.key (64 hex characters, mode 0600) instead of fresh keys")
    up.add_argument("--hosts", type=Path, default=None, metavar="HOSTS.yaml",
                    help="run the agents of some UAVs on other hosts: per host a command prefix that runs a command "
                    "there (e.g. [ssh, user@host]), its address and its UAV ids (the others run here). The world and "
                    "the broker stay here, listening on the hosts file's launcher address; each host needs Python with "
                    "plmarl_sitl installed, and gets its files (mission, policy, keys, login) through the prefix's "
                    "stdin. A host that falls silent mid-mission is recorded as node failures. Emulated autopilots only")
    up.add_argument("--json", action="store_true", help="print the summary as one JSON object at the end")
    up.add_argument("-v", "--verbose", action="store_true", help="agents log their debug lines too, and the start-up says how the swarm is secured (keys, broker logins)")
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


def autopilot_arg(text: str) -> tuple[str, Path | None]:
    """`emulator`, `arducopter=PATH` or `px4=PATH`."""
    kind, eq, path = text.partition("=")
    if kind == "emulator" and not eq:
        return "emulator", None
    if kind in ("arducopter", "px4") and path:
        return kind, Path(path).expanduser()
    raise argparse.ArgumentTypeError(f"{text!r}: expected emulator, arducopter=PATH (the arducopter binary) or px4=PATH "
                                     "(PX4's build/px4_sitl_default)")


def run_up(args: argparse.Namespace) -> int:
    from plmarl_sitl.errors import UserError
    from plmarl_sitl.sitl.autopilot.boot import check_boot
    from plmarl_sitl.sitl.launcher import ComponentFailed
    from plmarl_sitl.sitl.launcher import run_up as launch
    from plmarl_sitl.sitl.run_inputs import DEFAULT_POLICY, UpOptions

    args.speedup = speedup_or_default(args.speedup, args.lockstep)
    if args.speedup <= 0:
        raise UserError("--speedup must be > 0")
    check_boot(args.personality, args.boot)
    autopilot, binary = args.autopilot
    if autopilot == "emulator" and (args.copter_parm is not None or args.instance is not None):
        raise UserError("--copter-parm and --instance are for --autopilot arducopter=PATH or px4=PATH")
    if autopilot == "px4" and args.copter_parm is not None:
        raise UserError("--copter-parm is for --autopilot arducopter=PATH")
    if args.instance is not None and args.instance < 0:
        raise UserError("--instance must be >= 0")
    if args.duration is not None and args.duration < 1:
        raise UserError("--duration must be >= 1 s")
    if args.lockstep and autopilot != "emulator":
        raise UserError(f"--lockstep needs the emulated autopilots (a {autopilot} SITL runs a clock of its own)")
    if not args.straggler > 0:
        raise UserError("--straggler must be > 0 s")
    opts = UpOptions(
        mission_path=args.mission, speedup=args.speedup, duration_s=args.duration, broker=args.broker,
        headless=args.headless or args.json, out=args.out, seed=args.seed, policy=args.policy or DEFAULT_POLICY,
        personality=args.personality, boot=args.boot, swarm=args.swarm_name, autopilot=autopilot,
        arducopter=binary if autopilot == "arducopter" else None, px4=binary if autopilot == "px4" else None,
        copter_parm=args.copter_parm, instance_base=args.instance, verbose=args.verbose,
        auth=not args.no_auth, swarm_key=args.swarm_key, broker_credentials=args.broker_credentials,
        mavlink_sign=args.mavlink_sign, mavlink_keys=args.mavlink_keys,
        lockstep=args.lockstep, straggler_s=args.straggler, hosts=args.hosts,
    )
    try:
        summary = launch(opts)
    except ComponentFailed as exc:
        print(f"plmarl swarm up: failed: {exc.reason}", file=sys.stderr)
        return 1
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
