"""`plmarl agent --id I --connect URL --broker URL`: the PL-MARL agent for one UAV.

Runs next to a PX4 or ArduPilot autopilot (or the emulator): reads its telemetry, streams
acceleration setpoints, signals its state every T_up seconds over MQTT and flies the
TorchScript policy on Algorithm 1's beliefs. Ctrl-C hands the vehicle to its hold/brake
mode and exits.
"""

# The `plmarl agent` CLI registers this program's arguments (`add_arguments`, `run`);
# `main(argv)` runs it without the CLI (a forked agent in a SITL swarm). The second
# paragraph above is the --help description.

from __future__ import annotations

import os

# One BLAS thread: an agent shares the companion computer (and here, the cores) with others.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import asyncio  # noqa: E402
import logging  # noqa: E402
import signal  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

from plmarl_sitl.cmdline import rt_priority_arg, swarm_name_arg, tup_arg  # noqa: E402
from plmarl_sitl.config import PAPER_MISSION, PROJECT_POLICIES  # noqa: E402
from plmarl_sitl.deploy.agent.config import MAX_AIRFRAME_DRAG_PER_S, StartupBounds  # noqa: E402
from plmarl_sitl.deploy.mavlink.personality import PERSONALITIES  # noqa: E402
from plmarl_sitl.errors import UserError, run_reporting  # noqa: E402
from plmarl_sitl.mission import MAX_UAVS  # noqa: E402

PROG = "plmarl agent"
HELP = "run the PL-MARL agent for one UAV (MAVLink + MQTT + TorchScript policy)"
DESCRIPTION = __doc__.split("\n\n")[1].replace("\n", " ")
# The shipped mission and policy, found from the installed project (not the current
# directory): an agent started from anywhere flies them.
DEFAULT_MISSION = PAPER_MISSION
DEFAULT_POLICY = PROJECT_POLICIES / "pl-marl"
BOUNDS = StartupBounds()
LOCKSTEP_COMMAND_TIMEOUT_S = 5.0  # per COMMAND_LONG try with --lockstep (3 tries; 1 s against a real autopilot)
# --lockstep: the least start-up wait for what the vehicle clock brings (its heartbeat, home,
# position stream). `swarm up` runs that clock only once it has forked every agent: 100
# agents on a loaded 2-core machine took 96-210 s to fork (issue 25), and the agents forked
# first waited out the default bounds, sized for a running autopilot, before it started.
LOCKSTEP_STARTUP_WAIT_S = 600.0

EPILOG = """\
examples:
  plmarl agent --id 0 --connect udpout://127.0.0.1:14540 --broker mqtt://127.0.0.1:1883 --swarm-key swarm.key
  plmarl agent --id 2 --connect udpin://0.0.0.0:14550 --broker mqtt://10.0.0.1 --bus direct --no-takeoff \\
      --swarm-key swarm.key --broker-credentials agent2.cred
  plmarl agent --id 0 --connect tcpout://127.0.0.1:5760 --broker mqtt://127.0.0.1 --bus direct \\
      --n-uavs 1 --no-auth      # a real ArduCopter SITL (SERIAL0), started at the mission's launch point
  plmarl agent --id 1 --connect serial:///dev/ttyACM0:57600 --broker mqtt://10.0.0.1 --autopilot ardupilot \\
      --swarm-key swarm.key --rt-priority 20   # SCHED_FIFO, as for any control loop on a companion computer"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--id", type=_count_arg("--id", 0, MAX_UAVS - 1), required=True, help="this UAV's index in the mission (0..N-1)")
    p.add_argument("--connect", required=True, metavar="URL",
                   help="autopilot: udpout://HOST:PORT, udpin://BIND:PORT, tcpout://HOST:PORT, serial:///dev/X:BAUD")
    p.add_argument("--broker", required=True, metavar="URL", help="MQTT broker, mqtt://HOST:PORT")
    p.add_argument("--broker-credentials", default=None, metavar="FILE",
                   help="this agent's broker login: a file with one line USERNAME:PASSWORD, mode 0600 (default: anonymous)")
    p.add_argument("--mission", default=str(DEFAULT_MISSION), help=f"mission YAML (default: the project's {DEFAULT_MISSION})")
    p.add_argument("--n-uavs", type=_count_arg("--n-uavs", 1, MAX_UAVS), default=None, help="override the mission's number of UAVs (must match the world)")
    p.add_argument("--policy", default=str(DEFAULT_POLICY), help=f"policy directory (default: the project's {DEFAULT_POLICY})")
    p.add_argument("--autopilot", choices=["auto", *PERSONALITIES], default="auto",
                   help="expected autopilot (default auto: from the heartbeat)")
    p.add_argument("--tup", type=tup_arg, default=None, help="signalling interval T_up, s (default: the mission's)")
    p.add_argument("--swarm", type=swarm_name_arg, default="sitl", help="swarm name: topics plmarl/<swarm>/... (default sitl)")
    p.add_argument("--bus", choices=["sitl", "direct"], default="sitl",
                   help="sitl: the world's link emulator delivers rx/<id>; direct: subscribe tx/+ (radios bridged to a broker)")
    a = p.add_mutually_exclusive_group()
    a.add_argument("--swarm-key", default=None, metavar="FILE",
                   help="the swarm key (64 hex characters, mode 0600): sign every message sent, drop every message "
                   "received that does not authenticate (docs/SECURITY.md). Required unless --no-auth")
    a.add_argument("--no-auth", action="store_true",
                   help="fly with unsigned version-1 messages: anyone who can publish on the broker can steer the agent")
    p.add_argument("--mavlink-key", default=None, metavar="FILE",
                   help="MAVLink 2 signing key of this UAV's autopilot (64 hex characters, mode 0600): sign everything "
                   "sent to it and accept only its signed messages (default: an unsigned link; docs/SECURITY.md)")
    p.add_argument("--no-takeoff", action="store_true", help="attach to an airborne, armed vehicle instead of taking off")
    p.add_argument("--lockstep", action="store_true",
                   help="lockstep SITL (a world run with --lockstep): stamp each setpoint with the telemetry it answers and "
                        "answer a second's telemetry only after the world's tick for it; decisions never wait on wall time; "
                        "telemetry, and so setpoints, at 5 Hz of vehicle time (10 Hz otherwise)")
    p.add_argument("--start", choices=["wait", "now"], default=None,
                   help="wait: mission clock from the world's start announcement (default with --bus sitl); "
                   "now: start at once (default with --bus direct)")
    p.add_argument("--airframe-drag", type=float, default=0.0, metavar="PER_S",
                   help="the airframe's linear drag per unit mass, 1/s, added back to each acceleration setpoint's horizontal part (k v) "
                   "for an autopilot that flies them open loop: 1 for a PX4 SIH quadrotor (SIH_KDV / SIH_MASS); "
                   "default 0 (the emulator, ArduCopter)")
    p.add_argument("--trace", default=None, metavar="PATH", help="write one JSON line per mission second (P-AoI, N_i, f, action)")
    p.add_argument("--stats-json", default=None, metavar="PATH", help="write loop timing, RSS and counters here on exit")
    p.add_argument("--rt-priority", type=rt_priority_arg(), default=None, metavar="P",
                   help="run under SCHED_FIFO at priority P (1-99), as a control loop on a companion computer "
                   "should: then no normal-priority process preempts a decision (needs CAP_SYS_NICE; default off)")
    b = p.add_argument_group("start-up bounds (wall seconds each; a real ArduCopter SITL at 1x sets its home "
                             "~20 s and streams its position ~40 s after the link comes up)")
    b.add_argument("--wait-heartbeat", type=_seconds, default=BOUNDS.heartbeat_s, metavar="S",
                   help=f"for an autopilot heartbeat (default {BOUNDS.heartbeat_s:g})")
    b.add_argument("--wait-home", type=_seconds, default=BOUNDS.home_s, metavar="S",
                   help=f"for the home position (default {BOUNDS.home_s:g})")
    b.add_argument("--wait-position", type=_seconds, default=BOUNDS.position_s, metavar="S",
                   help=f"for the local position stream (default {BOUNDS.position_s:g})")
    b.add_argument("--wait-arm", type=_seconds, default=BOUNDS.arm_s, metavar="S",
                   help=f"for the autopilot to accept the offboard mode and arming (default {BOUNDS.arm_s:g})")
    p.add_argument("-v", "--verbose", action="store_true", help="also log the agent's debug lines")
    p.add_argument("-q", "--quiet", action="store_true", help="log warnings and errors only (no start-up progress)")


def _count_arg(flag: str, lo: int, hi: int):  # noqa: ANN202 - an argparse type
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"{value} is outside {lo}..{hi}")
        return value

    return parse


def _seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of seconds") from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f"{text!r}: must be > 0 s")
    return value


def _output_path(flag: str, path: str | None) -> Path | None:
    """An output file's path, its directory checked now (not after the flight)."""
    if path is None:
        return None
    out = Path(path)
    if not out.parent.is_dir():
        raise UserError(f"{flag} {path}: no such directory {out.parent}")
    return out


def run(args: argparse.Namespace) -> int:
    """The parsed program: load, build the agent with its bus and link, fly; the exit code."""
    import dataclasses

    from plmarl_sitl.deploy.agent.preload import preloaded_mission
    from plmarl_sitl.mission import load_mission

    # The user's mistakes first, in one line, before seconds of torch imports and policy loading.
    # A forked SITL agent may find the mission loaded by its forkserver (deploy/agent/preload.py).
    mission = preloaded_mission(args.mission) or load_mission(args.mission)
    if args.n_uavs is not None:
        mission = dataclasses.replace(mission, n_uavs=args.n_uavs)
    if not args.id < mission.n_uavs:
        raise UserError(f"--id {args.id}: the mission has {mission.n_uavs} UAVs (ids 0..{mission.n_uavs - 1}; "
                        "--n-uavs N to fly another swarm size)")
    if not 0.0 <= args.airframe_drag <= MAX_AIRFRAME_DRAG_PER_S:
        raise UserError(f"--airframe-drag {args.airframe_drag:g}: must be 0..{MAX_AIRFRAME_DRAG_PER_S:g} /s")
    if not Path(args.policy).is_dir():
        raise UserError(f"{args.policy}: missing policy directory (train one with `plmarl train`, or pass --policy)")

    import torch

    from plmarl_sitl.deploy.agent.config import AgentConfig
    from plmarl_sitl.deploy.agent.core import Agent
    from plmarl_sitl.deploy.agent.inbox import subscriptions
    from plmarl_sitl.deploy.agent.preload import preloaded, release_free_heap
    from plmarl_sitl.deploy.agent.stats import process_start_time
    from plmarl_sitl.deploy.mavlink.connect import connect, parse_url
    from plmarl_sitl.deploy.mavlink.keys import load_mavlink_key
    from plmarl_sitl.deploy.mqtt.auth import key_from_flags
    from plmarl_sitl.deploy.mqtt.credentials import load_credentials
    from plmarl_sitl.deploy.mqtt.schema import Topics
    from plmarl_sitl.deploy.mqtt.transport import MqttBus
    from plmarl_sitl.learning.nn.card import swarm_size_warning
    from plmarl_sitl.learning.nn.io import load_policy

    torch.set_num_threads(1)
    # INFO by default: start-up says what it waits for (a real autopilot takes tens of seconds).
    logging.basicConfig(level=logging.WARNING if args.quiet else logging.INFO,
                        format=f"%(asctime)s agent{args.id} %(levelname)s %(message)s", stream=sys.stderr)
    if args.verbose:
        logging.getLogger("plmarl").setLevel(logging.DEBUG)
    parse_url(args.connect)  # bad URLs fail before anything slow
    mavlink_key = load_mavlink_key(args.mavlink_key) if args.mavlink_key else None
    swarm_key = key_from_flags(args.swarm_key, args.no_auth)
    if swarm_key is None:
        logging.getLogger("plmarl.agent").warning("--no-auth: messages are unsigned; anyone who can publish on the "
                                                  "broker can steer this agent")
    credentials = load_credentials(args.broker_credentials) if args.broker_credentials else None
    t_imports = time.time() - process_start_time()
    # A forked SITL agent may find the policy loaded by its forkserver (deploy/agent/preload.py).
    lp = preloaded(args.policy, args.mission) if args.n_uavs is None else None
    how = "preloaded by the forkserver" if lp is not None else "loaded"
    lp = lp or load_policy(args.policy, mission)
    size_warning = swarm_size_warning(lp.card, mission.n_uavs)
    if size_warning is not None:
        logging.getLogger("plmarl.agent").warning("%s", size_warning)
    logging.getLogger("plmarl.agent").info(
        "start-up: interpreter + imports %.2f s, policy %s at %.2f s", t_imports, how, time.time() - process_start_time()
    )
    start = args.start or ("wait" if args.bus == "sitl" else "now")
    if args.lockstep and (args.bus != "sitl" or start != "wait"):
        raise UserError("--lockstep needs a lockstep SITL world: --bus sitl and --start wait")
    cfg = AgentConfig(
        uav_id=args.id,
        connect_url=args.connect,
        mission=mission,
        autopilot=args.autopilot,
        tup_s=args.tup,
        swarm=args.swarm,
        bus_mode=args.bus,
        takeoff=not args.no_takeoff,
        wait_start=start == "wait",
        bounds=_lockstep_bounds(StartupBounds(args.wait_heartbeat, args.wait_home, args.wait_position, args.wait_arm),
                                args.lockstep),
        trace_path=_output_path("--trace", args.trace),
        stats_path=_output_path("--stats-json", args.stats_json),
        swarm_key=swarm_key,
        lockstep=args.lockstep,
        airframe_drag_per_s=args.airframe_drag,
    )
    if cfg.airframe_drag_per_s:
        logging.getLogger("plmarl.agent").info("adding the airframe's drag back: %g /s x the horizontal velocity "
                                               "on each acceleration setpoint", cfg.airframe_drag_per_s)
    me, swarm = cfg.uav_id, cfg.swarm
    # The bus hands each message to the agent built just below (nothing arrives before `agent.run`).
    bus = MqttBus(args.broker, f"plmarl-{swarm}-agent-{me}-{cfg.session_id:04x}", subscriptions(Topics(swarm), me, cfg.bus_mode, cfg.lockstep),
                  lambda topic, payload: agent.inbox.on_message(topic, payload), name=f"agent{me}-bus", credentials=credentials)
    link = connect(args.connect, signing_key=mavlink_key)
    if cfg.lockstep:  # the emulated autopilots' world may be starved while 100 agents start (issue 25)
        link.command_timeout_s = LOCKSTEP_COMMAND_TIMEOUT_S
    link.stamp_arrivals = cfg.stats_path is not None  # only when measuring (one ioctl per datagram)
    agent = Agent(cfg, lp, bus, link)
    # Building the team plan's grid (here, unless a forkserver preloaded it) frees ~11 MB of
    # transients at 3 km that glibc keeps resident: handed back, not held through the flight.
    release_free_heap()
    if args.rt_priority is not None:
        # After the imports and the policy load (seconds of CPU a FIFO task would take
        # from everything else), before the first MAVLink message.
        from plmarl_sitl.proc import use_realtime

        use_realtime(args.rt_priority)
        logging.getLogger("plmarl.agent").info("running under SCHED_FIFO, priority %d", args.rt_priority)
    try:
        return asyncio.run(_fly(agent))
    finally:
        # The stop path has run (vehicle held, stats written); what is left is the interpreter's
        # exit, which takes a second or more with torch loaded on a busy machine. The closed loop
        # has put the default signal actions back, so a second SIGTERM (or SIGUSR1) there (a
        # launcher stopping its fleet) would turn a clean exit into "killed by a signal".
        for sig in STOP_SIGNALS:
            signal.signal(sig, signal.SIG_IGN)


def _lockstep_bounds(b: StartupBounds, lockstep: bool) -> StartupBounds:
    """Lockstep: the vehicle-clock waits at least LOCKSTEP_STARTUP_WAIT_S (see there)."""
    if not lockstep:
        return b
    w = LOCKSTEP_STARTUP_WAIT_S
    return StartupBounds(max(b.heartbeat_s, w), max(b.home_s, w), max(b.position_s, w), b.arm_s)


STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGUSR1)  # stop (hold the vehicle); SIGUSR1: release it


async def _fly(agent) -> int:  # noqa: ANN001 - core.Agent, imported lazily
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, agent.request_stop, f"{sig.name}: the vehicle to its stop mode")
    loop.add_signal_handler(signal.SIGUSR1, agent.release)
    return await agent.run()


def parser() -> argparse.ArgumentParser:
    """The program's own parser: the same prog, help and flags as `plmarl agent`."""
    p = argparse.ArgumentParser(prog=PROG, description=DESCRIPTION, epilog=EPILOG,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(p)
    return p


def main(argv: list[str]) -> int:
    """`plmarl agent ARGV` without the CLI around it: the same output and exit codes
    (`errors.run_reporting`: one line on stderr; user errors 2, vehicle failures 3,
    Ctrl-C before the agent flies 130)."""
    args = parser().parse_args(argv)
    return run_reporting(PROG, lambda: run(args))
