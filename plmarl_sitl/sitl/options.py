"""What a SITL run is asked, each option declared once: its default, its flag and its help.

* `SwarmOptions`: what every SITL world is flown with, whoever starts it (the swarm's
  name, the emulated autopilots' personality and boot, the clock: speedup, lockstep,
  straggler bound; the seed);
* `WorldOptions`: what `plmarl world` run on its own is also asked (its ports, the link
  emulator's extra loss and latency, the episode, external vehicles); `swarm up` decides
  these itself;
* `UpOptions`: what `plmarl swarm up` is asked (the broker, the autopilots, keys, hosts).

`sitl.world.WorldConfig` is a `WorldOptions` plus what the program loads or decides
(the mission, the broker URL, the keys, the events), so a world built by the CLI, by the
launcher, by a benchmark or by a test has the same fields with the same defaults and
checks. Each command adds the fields to its parser with `cmdline.add_flags` and builds
them from what was parsed with `cmdline.from_flags`; an impossible combination is one
UserError line on construction.

This module is light (no torch, no world): every `plmarl` command registers its parser
from it at start-up.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, fields
from pathlib import Path

from plmarl_sitl.cmdline import MAX_SEED, flag, seed_arg, speedup_arg, swarm_name_arg
from plmarl_sitl.config import PROJECT_POLICIES
from plmarl_sitl.errors import UserError
from plmarl_sitl.sitl.lockstep import DEFAULT_STARTUP_SPEEDUP, DEFAULT_STRAGGLER_S, speedup_or_default

DEFAULT_POLICY = PROJECT_POLICIES / "pl-marl"
AUTOPILOTS = ("emulator", "arducopter", "px4")
OWN_BROKERS = ("embedded", "mosquitto")  # brokers swarm up starts itself (fresh logins)


@dataclass(frozen=True, kw_only=True)
class SwarmOptions:
    swarm: str = flag("--swarm", "--swarm-name", type=swarm_name_arg, metavar="NAME", default="sitl",
                      help="swarm name: the MQTT topic namespace plmarl/NAME/... (default sitl)")
    personality: str = flag("--personality", choices=["px4", "ardupilot"], default="px4",
                            help="which autopilot the emulated vehicles behave as: its modes, units, start-up and "
                            "failsafes (default px4)")
    boot: str = flag("--boot", choices=["instant", "real"], default="instant",
                     help="the emulated autopilots' start-up: instant (home and position at once, default) or real "
                     "(ArduCopter's measured timeline: home after ~19 s, position after ~40 s of sim time)")
    # None: real time, or DEFAULT_STARTUP_SPEEDUP with lockstep (set on construction).
    speedup: float = flag("--speedup", type=speedup_arg, metavar="X", default=None,  # type: ignore[assignment]
                          help="sim seconds per wall second (default 1, real time; with --lockstep: the pace of the "
                          f"start-up only, default {DEFAULT_STARTUP_SPEEDUP:g})")
    # Lockstep (emulated vehicles only, `sitl.lockstep`): vehicle time waits for every member
    # agent's answer to each telemetry sample and for the tx of each instant; the speedup
    # then paces only the start-up.
    lockstep: bool = flag("--lockstep", action="store_true", default=False,
                          help="lockstep SITL: vehicle time waits for every agent's answer to each telemetry sample "
                          "(5 Hz of vehicle time; the agents run with --lockstep), so the run is as fast as the agents compute, never late, "
                          "and the same mission and seed give the same metrics.jsonl, events.jsonl and summary "
                          "(emulated autopilots only)")
    straggler_s: float = flag("--straggler", type=float, metavar="S", default=DEFAULT_STRAGGLER_S,
                              help="with --lockstep: an agent that owes an answer for S wall seconds is declared "
                              "failed and its vehicle left to its failsafe (swarm up also kills the agent); the "
                              f"mission goes on (default {DEFAULT_STRAGGLER_S:g})")
    seed: int | None = flag("--seed", type=seed_arg, default=None,  # None: the mission's
                            help=f"random seed 0..{MAX_SEED}; same seed, same numbers (default: the mission's seed)")

    def __post_init__(self) -> None:
        from plmarl_sitl.sitl.autopilot.boot import check_boot

        object.__setattr__(self, "speedup", speedup_or_default(self.speedup, self.lockstep))
        if not self.speedup > 0:
            raise UserError("--speedup must be > 0")
        if not self.straggler_s > 0:
            raise UserError("--straggler must be > 0 s")
        check_boot(self.personality, self.boot)


def swarm_options(opts: SwarmOptions) -> dict:
    """The `SwarmOptions` fields of `opts` (an `UpOptions`, say), to build a WorldConfig with."""
    return {f.name: getattr(opts, f.name) for f in fields(SwarmOptions)}


def external_urls(text: str) -> tuple[str, ...]:
    """An argparse `type` for --external: URL[,URL...], each a MAVLink connection URL."""
    from plmarl_sitl.deploy.mavlink.connect import parse_url

    urls = tuple(u.strip() for u in text.split(",") if u.strip())
    if not urls:
        raise argparse.ArgumentTypeError("expected URL[,URL...]")
    for url in urls:
        try:
            parse_url(url)
        except UserError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
    return urls


@dataclass(frozen=True, kw_only=True)
class WorldOptions(SwarmOptions):
    base_port: int = flag("--base-port", type=int, metavar="PORT", default=14540,
                          help="UDP port of emulated vehicle 0; vehicle i listens on PORT + i (default 14540)")
    n_uavs: int | None = flag("--n-uavs", type=int, metavar="N", default=None,
                              help="override the mission's number of UAVs (default: the mission's)")
    loss: float = flag("--loss", type=float, metavar="P", default=0.0,
                       help="extra per-delivery loss probability, 0..1, on top of the mission's channel (default 0)")
    latency_s: float = flag("--latency", type=float, metavar="S", default=0.0,
                            help="delivery latency, sim seconds (default 0)")
    episode_s: int | None = flag("--episode", type=int, metavar="S", default=None,
                                 help="stop after S mission seconds and print the mean coverage (default: run until "
                                 "Ctrl-C)")
    # MAVLink URLs of vehicles that fly elsewhere, one per UAV (then no emulated autopilots:
    # personality, boot and base_port do not apply); empty: the emulator in this process.
    external: tuple[str, ...] = flag("--external", type=external_urls, metavar="URL[,URL...]", default=(),
                                     help="vehicles that run elsewhere, one MAVLink URL per UAV in order "
                                     "(tcpout://HOST:PORT, udpin://BIND:PORT, udpout://HOST:PORT): no emulated "
                                     "autopilots; positions, modes and clocks from these links (a link of the world's "
                                     "own: ArduPilot SITL SERIAL1, PX4's GCS link, a MAVLink router output)")

    def __post_init__(self) -> None:
        super().__post_init__()
        if not 0 <= self.loss <= 1:
            raise UserError("--loss must be in [0, 1]")
        if not self.latency_s >= 0:
            raise UserError("--latency must be >= 0 s")
        if self.lockstep and self.external:
            raise UserError("--lockstep needs the emulated vehicles (external autopilots run clocks of their own)")


def policy_arg(text: str) -> Path:
    """A policy directory; a bare name that is not one (e.g. `service`) is the project's policies/NAME."""
    path = Path(text)
    if not path.is_dir() and len(path.parts) == 1 and (PROJECT_POLICIES / text).is_dir():
        return PROJECT_POLICIES / text
    return path


class AutopilotFlag(argparse.Action):
    """--autopilot `emulator`, `arducopter=PATH` or `px4=PATH`: sets `autopilot` (the kind)
    and `autopilot_path`."""

    def __call__(self, parser, namespace, values, option_string=None) -> None:  # noqa: ANN001
        kind, eq, path = str(values).partition("=")
        if not ((kind == "emulator" and not eq) or (kind in ("arducopter", "px4") and path)):
            raise argparse.ArgumentError(self, f"{values!r}: expected emulator, arducopter=PATH (the arducopter "
                                               "binary) or px4=PATH (PX4's build/px4_sitl_default)")
        namespace.autopilot = kind
        namespace.autopilot_path = Path(path).expanduser() if path else None


@dataclass(frozen=True)
class UpOptions(SwarmOptions):
    mission_path: Path = flag(type=Path, metavar="mission", help="mission YAML, e.g. missions/paper_urban.yaml")
    duration_s: int | None = flag("--duration", type=int, metavar="S", default=None,
                                  help="mission seconds to fly (default: the mission's episode length)")
    broker: str = flag("--broker", metavar="embedded|mosquitto|mqtt://HOST:PORT", default="embedded",
                       help="MQTT broker: embedded (amqtt in a child process, default), mosquitto (a mosquitto "
                       "child), both with a login per process and an ACL; or an external broker by URL (its access "
                       "control is its own)")
    headless: bool = flag("--headless", action="store_true", default=False,
                          help="no live view: one status line every 10 s of sim time")
    out: Path | None = flag("--out", type=Path, metavar="DIR", default=None,
                            help="run directory (default runs/<timestamp>)")
    policy: Path = flag("--policy", type=policy_arg, metavar="DIR|NAME", default=DEFAULT_POLICY,
                        help="policy directory, or the name of one of the project's (policies/NAME: pl-marl, gru, "
                        "tag-mappo, or service, the plan follower, not learnt); default policies/pl-marl")
    # The autopilots: "emulator" (in the world's process, `personality`, `boot`) or
    # "arducopter" (a real ArduCopter SITL process per UAV, `autopilot_path` the binary
    # `arducopter`) or "px4" (a real PX4 SITL process with SIH per UAV, `autopilot_path` its
    # build output).
    autopilot: str = flag("--autopilot", action=AutopilotFlag, also=("autopilot_path",), default="emulator",
                          metavar="emulator|arducopter=PATH|px4=PATH",
                          help="the autopilots: emulator (the point-mass emulator in the world's process, default), "
                          "arducopter=PATH (one real ArduCopter SITL process per UAV, PATH the `arducopter` binary "
                          "built from ArduPilot's source; its home at the mission's launch slot, its clock sped up by "
                          "--speedup) or px4=PATH (one real PX4 SITL process with its SIH quadrotor per UAV, PATH "
                          "PX4's build output build/px4_sitl_default; home at the launch slot, PX4_SIM_SPEED_FACTOR "
                          "= --speedup; unsigned: PX4 has no MAVLink signing)")
    autopilot_path: Path | None = None
    copter_parm: Path | None = flag("--copter-parm", type=Path, metavar="FILE", default=None,
                                    help="with arducopter: ArduPilot's copter.parm (default: "
                                    "Tools/autotest/default_params/copter.parm in the ArduPilot tree the binary was "
                                    "built in)")
    instance_base: int | None = flag("--instance", type=int, metavar="I", default=None,
                                     help="with arducopter: UAV i runs as ArduPilot SITL instance -I I+i, ports "
                                     "5760 + 10 (I+i); with px4: as PX4 instance -i I+i (at most 9), udp 18570 + I+i "
                                     "(world) and 14540 + I+i (agent) (default: the first instances whose ports are "
                                     "free)")
    # An external broker's logins: DIR/world.cred, DIR/monitor.cred, DIR/agentI.cred (None: anonymous).
    broker_credentials: Path | None = flag("--broker-credentials", type=Path, metavar="DIR", default=None,
                                           help="with an external broker: the logins it knows this swarm by, "
                                           "DIR/world.cred, DIR/monitor.cred and DIR/agentI.cred (one line "
                                           "USERNAME:PASSWORD each, mode 0600)")
    # Message authentication (docs/SECURITY.md): a fresh swarm key per run in the run
    # directory (swarm.key, 0600), or the key file given; auth=False flies unsigned.
    swarm_key: Path | None = flag("--swarm-key", type=Path, metavar="FILE", default=None, group="auth",
                                  help="sign every message with this key file (64 hex characters, mode 0600; default: "
                                  "a fresh key in the run directory, swarm.key)")
    auth: bool = flag("--no-auth", action="store_false", default=True, group="auth",
                      help="fly with unsigned messages (anyone who can publish on the broker can steer the swarm)")
    # MAVLink 2 signing between each autopilot and its agent (and the world's links): a fresh
    # key per vehicle in RUN_DIR/mavlink/vehicleI.key (0600), or DIR/vehicleI.key given.
    mavlink_sign: bool = flag("--mavlink-sign", action=argparse.BooleanOptionalAction, default=True,
                              help="MAVLink 2 signing between each autopilot and its agent, and on the world's links "
                              "(default on: a fresh key per vehicle in RUN_DIR/mavlink/vehicleI.key, 0600; a real "
                              "ArduCopter gets it by SETUP_SIGNING). Unsigned or badly signed commands and setpoints "
                              "are then dropped and counted")
    mavlink_keys: Path | None = flag("--mavlink-keys", type=Path, metavar="DIR", default=None,
                                     help="with --mavlink-sign: use DIR/vehicleI.key (64 hex characters, mode 0600) "
                                     "instead of fresh keys")
    hosts: Path | None = flag("--hosts", type=Path, metavar="HOSTS.yaml", default=None,  # `sitl.hosts`
                              help="run the agents of some UAVs on other hosts: per host a command prefix that runs a "
                              "command there (e.g. [ssh, user@host]), its address and its UAV ids (the others run "
                              "here). The world and the broker stay here, listening on the hosts file's launcher "
                              "address; each host needs Python with plmarl_sitl installed, and gets its files "
                              "(mission, policy, keys, login) through the prefix's stdin. A host that falls silent "
                              "mid-mission is recorded as node failures. Emulated autopilots only")
    verbose: bool = flag("-v", "--verbose", action="store_true", default=False,
                         help="agents log their debug lines too, and the start-up says how the swarm is secured "
                         "(keys, broker logins)")
    start_timeout_s: float | None = None  # wall s for every vehicle to get airborne (None: 120; real autopilots: more)

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.autopilot not in AUTOPILOTS or (self.autopilot_path is None) != (self.autopilot == "emulator"):
            raise UserError(f"autopilot {self.autopilot!r} (path {self.autopilot_path}): expected emulator, "
                            "arducopter with its binary or px4 with its build")
        if self.autopilot == "emulator" and (self.copter_parm is not None or self.instance_base is not None):
            raise UserError("--copter-parm and --instance are for --autopilot arducopter=PATH or px4=PATH")
        if self.autopilot == "px4" and self.copter_parm is not None:
            raise UserError("--copter-parm is for --autopilot arducopter=PATH")
        if self.instance_base is not None and self.instance_base < 0:
            raise UserError("--instance must be >= 0")
        if self.duration_s is not None and self.duration_s < 1:
            raise UserError("--duration must be >= 1 s")
        if self.lockstep and self.autopilot != "emulator":
            raise UserError(f"--lockstep needs the emulated autopilots (a {self.autopilot} SITL runs a clock of its own)")
        if self.mavlink_keys is not None and not self.mavlink_sign:
            raise UserError("--mavlink-keys with --no-mavlink-sign: choose one")
        if self.mavlink_keys is not None and self.autopilot == "px4":
            raise UserError("--mavlink-keys with --autopilot px4: PX4 has no MAVLink signing to give them to")
        if self.broker_credentials is not None and self.broker in OWN_BROKERS:
            raise UserError("--broker-credentials is for an external broker (the brokers swarm up starts get fresh logins)")

    @property
    def arducopter(self) -> Path | None:
        """The real ArduCopter SITL binary (`--autopilot arducopter=PATH`)."""
        return self.autopilot_path if self.autopilot == "arducopter" else None

    @property
    def px4(self) -> Path | None:
        """The real PX4 SITL build directory (`--autopilot px4=PATH`)."""
        return self.autopilot_path if self.autopilot == "px4" else None

    def start_timeout(self) -> float:
        """A real ArduCopter needs ~40 s of vehicle time to boot and a climb at 2.5 m/s; a real PX4
        ~37 s to OFFBOARD at 60 m (it climbs at ~2 m/s)."""
        if self.start_timeout_s is not None:
            return self.start_timeout_s
        return 120.0 if self.autopilot == "emulator" else max(120.0, 60.0 + 150.0 / self.speedup)
