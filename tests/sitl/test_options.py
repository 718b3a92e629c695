"""Each SITL option is declared once (`sitl.options`): the `plmarl world` and `plmarl swarm up`
parsers are built from the dataclasses, so what a command parses without flags is the
dataclass's default, the shared options mean the same on both commands, and an impossible
combination is one UserError whoever builds the options."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest

from plmarl_sitl.cli import build_parser
from plmarl_sitl.cmdline import from_flags
from plmarl_sitl.errors import UserError
from plmarl_sitl.mission import load_mission
from plmarl_sitl.sitl.lockstep import DEFAULT_STARTUP_SPEEDUP
from plmarl_sitl.sitl.options import SwarmOptions, UpOptions, WorldOptions
from plmarl_sitl.sitl.world import WorldConfig

ROOT = Path(__file__).resolve().parents[2]
MISSION = ROOT / "missions" / "paper_urban.yaml"


def _parse(*argv: str):  # noqa: ANN202 - argparse.Namespace
    return build_parser(argv[0]).parse_args(list(argv))


def _world(*flags: str) -> WorldConfig:
    args = _parse("world", str(MISSION), "--broker", "mqtt://127.0.0.1:1", "--no-auth", *flags)
    return from_flags(WorldConfig, args, mission=load_mission(MISSION), broker_url=args.broker)


def test_no_flags_give_the_dataclass_defaults() -> None:
    assert from_flags(UpOptions, _parse("swarm", "up", str(MISSION))) == UpOptions(MISSION)
    assert _world() == WorldConfig(load_mission(MISSION), "mqtt://127.0.0.1:1")


def test_the_shared_options_parse_the_same_on_both_commands() -> None:
    flags = ("--swarm-name", "blue", "--personality", "ardupilot", "--boot", "real", "--lockstep", "--straggler", "4",
             "--seed", "11")
    up = from_flags(UpOptions, _parse("swarm", "up", str(MISSION), *flags))
    world = _world(*flags)
    shared = [f.name for f in dataclasses.fields(SwarmOptions)]
    assert {n: getattr(up, n) for n in shared} == {n: getattr(world, n) for n in shared}
    assert (up.swarm, up.personality, up.boot, up.straggler_s, up.seed) == ("blue", "ardupilot", "real", 4.0, 11)
    assert up.speedup == world.speedup == DEFAULT_STARTUP_SPEEDUP  # lockstep without --speedup: the start-up pace
    assert from_flags(UpOptions, _parse("swarm", "up", str(MISSION), "--swarm", "red")).swarm == "red"


def test_flags_reach_their_fields() -> None:
    up = from_flags(UpOptions, _parse("swarm", "up", str(MISSION), "--autopilot", "px4=/opt/px4/build", "--no-auth",
                                      "--no-mavlink-sign", "--instance", "2", "--duration", "30", "--speedup", "3"))
    assert (up.autopilot, up.px4, up.arducopter, up.instance_base) == ("px4", Path("/opt/px4/build"), None, 2)
    assert (up.auth, up.mavlink_sign, up.duration_s, up.speedup) == (False, False, 30, 3.0)
    world = _world("--external", "udpout://127.0.0.1:5,udpout://127.0.0.1:6", "--n-uavs", "2", "--loss", "0.25",
                   "--latency", "0.5", "--episode", "40", "--base-port", "15000")
    assert world.external == ("udpout://127.0.0.1:5", "udpout://127.0.0.1:6")
    assert (world.n_uavs, world.loss, world.latency_s, world.episode_s, world.base_port) == (2, 0.25, 0.5, 40, 15000)


@pytest.mark.parametrize("build, says", [
    (lambda: WorldOptions(speedup=0.0), "--speedup must be > 0"),
    (lambda: WorldOptions(lockstep=True, straggler_s=0.0), "--straggler must be > 0"),
    (lambda: WorldOptions(boot="later"), "later"),
    (lambda: WorldOptions(loss=1.5), "--loss must be in [0, 1]"),
    (lambda: WorldOptions(lockstep=True, external=("udpout://127.0.0.1:5",)), "--lockstep needs the emulated"),
    (lambda: WorldConfig(load_mission(MISSION), "mqtt://x", external=("udpout://127.0.0.1:5",)), "1 URL(s) for 4 UAVs"),
    (lambda: UpOptions(MISSION, instance_base=3), "are for --autopilot"),
    (lambda: UpOptions(MISSION, lockstep=True, autopilot="arducopter", autopilot_path=Path("ac")), "--lockstep needs"),
    (lambda: UpOptions(MISSION, autopilot="px4"), "expected emulator"),
    (lambda: UpOptions(MISSION, duration_s=0), "--duration must be >= 1 s"),
    (lambda: UpOptions(MISSION, mavlink_keys=Path("k"), mavlink_sign=False), "choose one"),
    (lambda: UpOptions(MISSION, broker="mosquitto", broker_credentials=Path("c")), "is for an external broker"),
])
def test_impossible_options_are_one_user_error_whoever_builds_them(build, says: str) -> None:  # noqa: ANN001
    with pytest.raises(UserError) as exc:
        build()
    assert says in str(exc.value) and "\n" not in str(exc.value)
