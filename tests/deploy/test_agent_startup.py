"""The agent's start-up against autopilots that behave as real ones do (issue 13): the
`plmarl agent` process, real sockets, the emulator or a scripted MAVLink peer.

Each failure a user can cause or meet is one `plmarl agent: error:` line and a non-zero
exit, never a traceback; each wait is announced."""

from __future__ import annotations

import asyncio
import re
import signal
import time
from pathlib import Path

import pytest

from plmarl_sitl.config import VehicleModel
from plmarl_sitl.errors import EXIT_USER, EXIT_VEHICLE
from plmarl_sitl.mission import Origin, load_mission
from plmarl_sitl.sitl.network.broker import free_udp_ports, local_broker

from .agent_process import agent_argv, emulated_vehicle, run_agent, stop_at
from .conftest import MISSION
from .scripted_autopilot import ScriptedAutopilot

pytestmark = [pytest.mark.integration, pytest.mark.timeout(120)]

PAPER = load_mission(MISSION)
CANBERRA = Origin(-35.363262, 149.165237, 584.0)  # ArduPilot SITL's default home


def _no_traceback(err: str) -> None:
    assert "Traceback" not in err and "ExceptionGroup" not in err, err


def test_takeoff_climbs_to_the_height_above_home_when_home_is_above_the_mission_origin(policy_dir: Path) -> None:
    """Home 96 m above the mission origin (as ArduPilot's default home was, by altitude):
    a disarmed vehicle on the ground gets GUIDED, arm, takeoff, and the agent waits until
    it is 60 m above HOME, not until the mission frame says 60 m."""
    o = PAPER.origin
    seen: dict[str, float] = {}

    async def main():  # noqa: ANN202
        async with local_broker("amqtt") as broker, emulated_vehicle(origin=Origin(o.lat_deg, o.lon_deg, o.alt_m + 96.0)) as host:

            def on_line(line: str) -> bool:
                if "in GUIDED" in line:
                    seen["z"] = float(host.true_states()[0, 2])
                    return True
                return False

            return await run_agent(agent_argv(host.ports[0], broker.url, "--bus", "direct", "--policy", str(policy_dir)),
                                   on_line=on_line)

    run = asyncio.run(main())
    assert run.code == 0, run.err
    assert "taking off to 60 m above home" in run.err
    assert seen["z"] == pytest.approx(-60.0, abs=1.0), run.err  # local NED: 60 m above home
    # The take-off ends within 0.5 m of the target (its condition), read at 2 Hz during the climb.
    assert re.search(r"in GUIDED at (59\.[5-9]|6\d\.\d) m above home", run.err), run.err


def test_an_armed_vehicle_flying_at_mission_altitude_is_attached_to_not_taken_off_again(policy_dir: Path) -> None:
    async def main():  # noqa: ANN202
        async with local_broker("amqtt") as broker, emulated_vehicle() as host:
            v = host.vehicle(0)
            p = v.personality
            assert v.set_mode(p.mode("GUIDED")) == 0 and v.arm(False) == 0 and v.takeoff(60.0) == 0
            async with asyncio.timeout(30):
                while float(host.true_states()[0, 2]) > -59.5:
                    await asyncio.sleep(0.05)
            run = await run_agent(agent_argv(host.ports[0], broker.url, "--bus", "direct", "--policy", str(policy_dir)),
                                  on_line=stop_at("in GUIDED"))
            return run, float(host.true_states()[0, 2])

    run, z = asyncio.run(main())
    assert run.code == 0, run.err
    assert "attaching (no takeoff)" in run.err and "taking off" not in run.err, run.err
    assert z < -40.0  # still flying


def test_a_home_far_from_the_mission_is_one_line_naming_both_positions(policy_dir: Path) -> None:
    async def main():  # noqa: ANN202
        async with emulated_vehicle(origin=CANBERRA) as host:
            return await run_agent(agent_argv(host.ports[0], "mqtt://127.0.0.1:1", "--policy", str(policy_dir)))

    run = asyncio.run(main())
    _no_traceback(run.err)
    assert run.code == EXIT_USER
    [line] = run.errors()
    o = PAPER.origin
    assert "-35.363262, 149.165237" in line and f"{o.lat_deg:.6f}, {o.lon_deg:.6f}" in line, line
    assert "--home" in line


def test_started_from_another_directory_the_agent_finds_the_shipped_mission_and_policy(tmp_path: Path) -> None:
    """No --mission, no --policy, the current directory elsewhere: the project's own are used."""

    async def main():  # noqa: ANN202
        async with emulated_vehicle("px4") as host:
            return await run_agent(agent_argv(host.ports[0]), cwd=tmp_path, on_line=stop_at("ready after"))

    run = asyncio.run(main())
    assert run.code == 0, run.err
    assert "policy loaded" in run.err and "ready after" in run.err


def test_with_the_sitl_bus_and_no_world_the_agent_says_what_it_waits_for(policy_dir: Path) -> None:
    async def main():  # noqa: ANN202
        async with local_broker("amqtt") as broker, emulated_vehicle("px4") as host:
            return await run_agent(agent_argv(host.ports[0], broker.url, "--policy", str(policy_dir)),
                                   on_line=stop_at("waiting for the SITL world's start message"))

    run = asyncio.run(main())
    assert run.code == 0, run.err
    [line] = [x for x in run.err.splitlines() if "waiting for the SITL world's start message" in x]
    assert " INFO " in line and "plmarl/sitl/start" in line and "--bus direct" in line


def test_a_refused_command_is_one_line_and_exit_3(policy_dir: Path) -> None:
    """An airframe whose ceiling (30 m) is below the mission's takeoff altitude (60 m): the
    autopilot denies NAV_TAKEOFF."""
    low = VehicleModel("low", min_alt_m=5.0, max_alt_m=30.0, takeoff_alt_m=20.0)

    async def main():  # noqa: ANN202
        async with emulated_vehicle(vehicle=low) as host:
            return await run_agent(agent_argv(host.ports[0], "mqtt://127.0.0.1:1", "--policy", str(policy_dir)))

    run = asyncio.run(main())
    _no_traceback(run.err)
    assert run.code == EXIT_VEHICLE
    assert run.errors() == ["plmarl agent: error: vehicle 1: command MAV_CMD_NAV_TAKEOFF (22) rejected (MAV_RESULT_DENIED)"]


def test_no_heartbeat_is_one_line_naming_the_url_and_the_bound(policy_dir: Path) -> None:
    port = free_udp_ports(1)
    run = asyncio.run(run_agent(agent_argv(port, "mqtt://127.0.0.1:1", "--policy", str(policy_dir), "--wait-heartbeat", "1")))
    _no_traceback(run.err)
    assert run.code == EXIT_USER
    assert run.errors() == [f"plmarl agent: error: no autopilot heartbeat on udpout://127.0.0.1:{port} within 1 s "
                            "(is the autopilot running, and is this its address?)"]
    assert f"waiting up to 1 s for an autopilot heartbeat on udpout://127.0.0.1:{port}" in run.err


def test_a_home_and_a_position_that_come_late_are_waited_for(policy_dir: Path) -> None:
    """Home 4 s and the position stream 7 s after the link comes up (a real ArduCopter at
    about 5x): each wait is announced with its bound and start-up completes."""
    o = PAPER.origin

    async def main():  # noqa: ANN202
        ap = ScriptedAutopilot(home=(o.lat_deg, o.lon_deg, o.alt_m), home_after_s=4.0, position_after_s=7.0)
        port = await ap.serve_tcp()
        try:
            return await run_agent(agent_argv(f"tcpout://127.0.0.1:{port}", "mqtt://127.0.0.1:1", "--policy", str(policy_dir)),
                                   on_line=stop_at("ready after"))
        finally:
            ap.close()

    run = asyncio.run(main())
    assert run.code == 0, run.err
    assert "waiting up to 120 s for the autopilot's home position" in run.err
    assert "waiting up to 120 s for the autopilot's local position" in run.err
    assert "ready after" in run.err


def test_an_autopilot_that_never_sets_its_home_is_one_line_after_the_bound(policy_dir: Path) -> None:
    """It accepts REQUEST_MESSAGE(HOME_POSITION) and sends nothing, as ArduPilot does before
    its EKF has an origin."""

    async def main():  # noqa: ANN202
        ap = ScriptedAutopilot()
        port = await ap.serve_tcp()
        try:
            return await run_agent(agent_argv(f"tcpout://127.0.0.1:{port}", "mqtt://127.0.0.1:1", "--policy", str(policy_dir),
                                              "--wait-home", "5")), ap.commands
        finally:
            ap.close()

    run, commands = asyncio.run(main())
    _no_traceback(run.err)
    assert run.code == EXIT_VEHICLE
    assert run.errors() == ["plmarl agent: error: vehicle 1: no HOME_POSITION (the autopilot has not set its home) within 5 s"]
    assert "waiting up to 5 s for the autopilot's home position" in run.err
    assert sum(c == 512 for c, _ in commands) >= 2  # asked again while waiting


def test_an_autopilot_hanging_up_ends_the_agent_at_once(policy_dir: Path) -> None:
    """The TCP connection closes while the agent waits for home: LinkLost at once, not at a
    telemetry timeout."""

    async def main():  # noqa: ANN202
        ap = ScriptedAutopilot()
        port = await ap.serve_tcp()
        hung_up: list[float] = []
        reported: list[float] = []

        def on_line(line: str) -> None:
            if "waiting up to 60 s for the autopilot's home position" in line:
                ap.hang_up()
                hung_up.append(time.monotonic())
            if "link lost" in line:
                reported.append(time.monotonic())

        try:
            run = await run_agent(agent_argv(f"tcpout://127.0.0.1:{port}", "mqtt://127.0.0.1:1", "--policy", str(policy_dir),
                                             "--wait-home", "60"), on_line=on_line)
            return run, reported[0] - hung_up[0], port
        finally:
            ap.close()

    run, took, port = asyncio.run(main())
    _no_traceback(run.err)
    assert run.code == EXIT_VEHICLE
    # A hang-up is an EOF, or a reset when our requests were still unread in the peer's buffer.
    [line] = run.errors()
    assert re.fullmatch(rf"plmarl agent: error: vehicle 1: link lost \(tcp 127\.0\.0\.1:{port}: the autopilot "
                        r"(closed|reset) the connection\)", line), line
    assert took < 3.0  # hang-up to the error line; a telemetry timeout alone would be 5 s (the
    # process's own teardown after the line is not what this test is about, and takes seconds under load)


@pytest.mark.parametrize("argv,needle", [
    (["--broker", "ftp://x"], "broker URL 'ftp://x': scheme must be mqtt://"),
    (["--trace", "/nonexistent-dir/trace.jsonl"], "--trace /nonexistent-dir/trace.jsonl: no such directory /nonexistent-dir"),
    (["--mission", "no/such/mission.yaml"], "no/such/mission.yaml: cannot read file"),
])
def test_bad_flags_are_one_line_and_exit_2(argv: list[str], needle: str, policy_dir: Path) -> None:
    base = agent_argv(1, "mqtt://127.0.0.1:1", "--policy", str(policy_dir))
    run = asyncio.run(run_agent(base + argv, timeout_s=60))
    _no_traceback(run.err)
    assert run.code == EXIT_USER
    [line] = run.errors()
    assert needle in line, line


def test_the_autopilot_choices_are_the_personalities(capsys: pytest.CaptureFixture[str]) -> None:
    from plmarl_sitl.deploy.agent.program import parser
    from plmarl_sitl.deploy.mavlink.personality import PERSONALITIES

    base = ["--id", "0", "--connect", "udpout://127.0.0.1:1", "--broker", "mqtt://x", "--autopilot"]
    for name in ["auto", *PERSONALITIES]:
        assert parser().parse_args([*base, name]).autopilot == name
    with pytest.raises(SystemExit):
        parser().parse_args([*base, "betaflight"])
    assert f"choose from {', '.join(repr(x) for x in ['auto', *PERSONALITIES])}" in capsys.readouterr().err


def test_defaults_are_the_projects_not_the_current_directorys() -> None:
    from plmarl_sitl.deploy.agent.program import parser

    args = parser().parse_args(["--id", "0", "--connect", "udpout://127.0.0.1:1", "--broker", "mqtt://x"])
    assert Path(args.mission).is_absolute() and Path(args.mission).resolve() == MISSION.resolve()
    assert Path(args.policy).is_absolute() and Path(args.policy).is_dir()


def test_repeated_sigterm_while_stopping_still_exits_cleanly(policy_dir: Path) -> None:
    """A launcher stopping its fleet may SIGTERM an agent that is already on its way out:
    the agent holds the vehicle once and exits 0, never 'killed by SIGTERM' during the
    interpreter's exit (CI saw -15 on a loaded machine)."""

    async def main():  # noqa: ANN202
        async with local_broker("amqtt") as broker, emulated_vehicle() as host:
            return await run_agent(agent_argv(host.ports[0], broker.url, "--bus", "direct", "--policy", str(policy_dir)),
                                   on_line=stop_at("in GUIDED"), sig=signal.SIGTERM, repeat_every_s=0.01)

    run = asyncio.run(main())
    assert run.code == 0, run.err
    assert run.err.count("stopped: vehicle in BRAKE") == 1, run.err
    assert run.err.count("stopped (SIGTERM: the vehicle to its stop mode) after") == 1, run.err  # the stop reason
