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

from plmarl_sitl.cmdline import rt_priority_arg, tup_arg  # noqa: E402
from plmarl_sitl.config import ConfigError  # noqa: E402
from plmarl_sitl.errors import UserError  # noqa: E402

PROG = "plmarl agent"
HELP = "run the PL-MARL agent for one UAV (MAVLink + MQTT + TorchScript policy)"
DESCRIPTION = __doc__.split("\n\n")[1].replace("\n", " ")
DEFAULT_MISSION = "missions/paper_urban.yaml"

EPILOG = """\
examples:
  plmarl agent --id 0 --connect udpout://127.0.0.1:14540 --broker mqtt://127.0.0.1:1883
  plmarl agent --id 2 --connect udpin://0.0.0.0:14550 --broker mqtt://10.0.0.1 --bus direct --no-takeoff
  plmarl agent --id 1 --connect serial:///dev/ttyACM0:57600 --broker mqtt://10.0.0.1 --autopilot ardupilot \\
      --rt-priority 20          # SCHED_FIFO, as for any control loop on a companion computer"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--id", type=int, required=True, help="this UAV's index in the mission (0..N-1)")
    p.add_argument("--connect", required=True, metavar="URL",
                   help="autopilot: udpout://HOST:PORT, udpin://BIND:PORT, tcpout://HOST:PORT, serial:///dev/X:BAUD")
    p.add_argument("--broker", required=True, metavar="URL", help="MQTT broker, mqtt://HOST:PORT")
    p.add_argument("--mission", default=DEFAULT_MISSION, help=f"mission YAML (default {DEFAULT_MISSION})")
    p.add_argument("--n-uavs", type=int, default=None, help="override the mission's number of UAVs (must match the world)")
    p.add_argument("--policy", default="policies/pl-marl", help="policy directory (default policies/pl-marl)")
    p.add_argument("--autopilot", choices=["auto", "px4", "ardupilot"], default="auto",
                   help="expected autopilot (default auto: from the heartbeat)")
    p.add_argument("--tup", type=tup_arg, default=None, help="signalling interval T_up, s (default: the mission's)")
    p.add_argument("--swarm", default="sitl", help="swarm name: topics plmarl/<swarm>/... (default sitl)")
    p.add_argument("--bus", choices=["sitl", "direct"], default="sitl",
                   help="sitl: the world's link emulator delivers rx/<id>; direct: subscribe tx/+ (radios bridged to a broker)")
    p.add_argument("--no-takeoff", action="store_true", help="attach to an airborne, armed vehicle instead of taking off")
    p.add_argument("--start", choices=["wait", "now"], default=None,
                   help="wait: mission clock from the world's start announcement (default with --bus sitl); "
                   "now: start at once (default with --bus direct)")
    p.add_argument("--trace", default=None, metavar="PATH", help="write one JSON line per mission second (P-AoI, N_i, f, action)")
    p.add_argument("--stats-json", default=None, metavar="PATH", help="write loop timing, RSS and counters here on exit")
    p.add_argument("--rt-priority", type=rt_priority_arg(), default=None, metavar="P",
                   help="run under SCHED_FIFO at priority P (1-99), as a control loop on a companion computer "
                   "should: then no normal-priority process preempts a decision (needs CAP_SYS_NICE; default off)")
    p.add_argument("-v", "--verbose", action="store_true")


def run(args: argparse.Namespace) -> int:
    """The parsed program: load, build the agent with its bus and link, fly; the exit code."""
    import torch

    from plmarl_sitl.deploy.agent.config import AgentConfig
    from plmarl_sitl.deploy.agent.core import Agent
    from plmarl_sitl.deploy.agent.inbox import subscriptions
    from plmarl_sitl.deploy.agent.stats import process_start_time
    from plmarl_sitl.deploy.mavlink.connect import connect, parse_url
    from plmarl_sitl.deploy.mqtt.schema import Topics
    from plmarl_sitl.deploy.mqtt.transport import MqttBus
    from plmarl_sitl.learning.nn.io import load_policy
    from plmarl_sitl.mission import load_mission

    torch.set_num_threads(1)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format=f"%(asctime)s agent{args.id} %(levelname)s %(message)s", stream=sys.stderr)
    parse_url(args.connect)  # bad URLs fail before anything slow
    mission = load_mission(args.mission)
    if args.n_uavs is not None:
        import dataclasses

        if args.n_uavs < 1:
            raise UserError("--n-uavs must be >= 1")
        mission = dataclasses.replace(mission, n_uavs=args.n_uavs)
    if not Path(args.policy).is_dir():
        raise UserError(f"{args.policy}: missing policy directory (train one with `plmarl train`, or pass --policy)")
    t_imports = time.time() - process_start_time()
    lp = load_policy(args.policy, mission)
    logging.getLogger("plmarl.agent").info(
        "start-up: interpreter + imports %.2f s, policy loaded at %.2f s", t_imports, time.time() - process_start_time()
    )
    start = args.start or ("wait" if args.bus == "sitl" else "now")
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
        trace_path=Path(args.trace) if args.trace else None,
        stats_path=Path(args.stats_json) if args.stats_json else None,
    )
    me, swarm = cfg.uav_id, cfg.swarm
    # The bus hands each message to the agent built just below (nothing arrives before `agent.run`).
    bus = MqttBus(args.broker, f"plmarl-{swarm}-agent-{me}-{cfg.session_id:04x}", subscriptions(Topics(swarm), me, cfg.bus_mode),
                  lambda topic, payload: agent.inbox.on_message(topic, payload), name=f"agent{me}-bus")
    link = connect(args.connect)
    link.stamp_arrivals = cfg.stats_path is not None  # only when measuring (one ioctl per datagram)
    agent = Agent(cfg, lp, bus, link)
    if args.rt_priority is not None:
        # After the imports and the policy load (seconds of CPU a FIFO task would take
        # from everything else), before the first MAVLink message.
        from plmarl_sitl.proc import use_realtime

        use_realtime(args.rt_priority)
        logging.getLogger("plmarl.agent").info("running under SCHED_FIFO, priority %d", args.rt_priority)
    return asyncio.run(_fly(agent))


async def _fly(agent) -> int:  # noqa: ANN001 - core.Agent, imported lazily
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, agent.stop_event.set)
    return await agent.run()


def parser() -> argparse.ArgumentParser:
    """The program's own parser: the same prog, help and flags as `plmarl agent`."""
    p = argparse.ArgumentParser(prog=PROG, description=DESCRIPTION, epilog=EPILOG,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    add_arguments(p)
    return p


def main(argv: list[str]) -> int:
    """`plmarl agent ARGV` without the CLI around it: the same output and exit codes (user
    errors: one line and 2, Ctrl-C before the agent flies: 130)."""
    args = parser().parse_args(argv)
    try:
        return int(run(args) or 0)
    except (ConfigError, UserError) as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130
