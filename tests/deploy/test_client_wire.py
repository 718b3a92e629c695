"""The MAVLink client on the wire: the COMMAND_LONG params it sends (as the MAVLink spec and
ArduPilot's GCS_Common.cpp want them), a TCP autopilot hanging up, and one-line errors."""

from __future__ import annotations

import asyncio
import math
import socket
import time

import pytest

from plmarl_sitl.deploy.mavlink.codec import dialect as d
from plmarl_sitl.deploy.mavlink.connect import connect
from plmarl_sitl.errors import (
    EXIT_INTERRUPTED,
    EXIT_SYSTEM,
    EXIT_USER,
    EXIT_VEHICLE,
    CommandRejected,
    LinkLost,
    UserError,
    VehicleTimeout,
    run_reporting,
)

from .scripted_autopilot import ScriptedAutopilot

NAN = math.nan


def _same(a: tuple[float, ...], b: tuple[float, ...]) -> bool:
    return all((math.isnan(x) and math.isnan(y)) or x == y for x, y in zip(a, b, strict=True))


def test_command_params_follow_the_spec() -> None:
    """0 where a param is reserved or unused; NaN only where the command defines it as
    "current" (takeoff/land yaw and position). ArduPilot DENIES SET_MESSAGE_INTERVAL with
    NaN in its reserved param 3."""

    async def main() -> list[tuple[int, tuple[float, ...]]]:
        ap = ScriptedAutopilot()
        port = await ap.serve_udp()
        link = connect(f"udpout://127.0.0.1:{port}")
        try:
            await link.open(timeout=5.0)
            assert link.personality is not None and link.personality.name == "ardupilot"
            await link.set_message_interval("LOCAL_POSITION_NED", 10.0)
            await link.set_message_interval("ATTITUDE", 0.0)
            await link.request_message(d.MAVLINK_MSG_ID_HOME_POSITION)
            await link.set_mode("GUIDED")
            await link.arm()
            await link.takeoff(60.0)
            await link.land()
            await link.disarm(force=True)
        finally:
            link.close()
            ap.close()
        return ap.commands

    sent = asyncio.run(main())
    want = [
        (d.MAV_CMD_SET_MESSAGE_INTERVAL, (32, 100_000, 0, 0, 0, 0, 0)),
        (d.MAV_CMD_SET_MESSAGE_INTERVAL, (30, -1, 0, 0, 0, 0, 0)),
        (d.MAV_CMD_REQUEST_MESSAGE, (242, 0, 0, 0, 0, 0, 0)),
        (d.MAV_CMD_DO_SET_MODE, (d.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4, 0, 0, 0, 0, 0)),
        (d.MAV_CMD_COMPONENT_ARM_DISARM, (1, 0, 0, 0, 0, 0, 0)),
        (d.MAV_CMD_NAV_TAKEOFF, (0, 0, 0, NAN, NAN, NAN, 60)),
        (d.MAV_CMD_NAV_LAND, (0, 0, 0, NAN, NAN, NAN, NAN)),
        (d.MAV_CMD_COMPONENT_ARM_DISARM, (0, 21196, 0, 0, 0, 0, 0)),
    ]
    assert [c for c, _ in sent] == [c for c, _ in want]
    for (cmd, got), (_, exp) in zip(sent, want, strict=True):
        assert _same(got, exp), (cmd, got, exp)


def test_a_refusal_names_the_command_and_the_result() -> None:
    async def main() -> None:
        ap = ScriptedAutopilot(result=d.MAV_RESULT_DENIED)
        port = await ap.serve_udp()
        link = connect(f"udpout://127.0.0.1:{port}")
        try:
            await link.open(timeout=5.0)
            with pytest.raises(CommandRejected) as exc:
                await link.set_message_interval("LOCAL_POSITION_NED", 10.0)
            assert str(exc.value) == "vehicle 1: command MAV_CMD_SET_MESSAGE_INTERVAL (511) rejected (MAV_RESULT_DENIED)"
        finally:
            link.close()
            ap.close()

    asyncio.run(main())


def test_a_tcp_autopilot_hanging_up_ends_every_wait_at_once() -> None:
    async def main() -> None:
        ap = ScriptedAutopilot()
        port = await ap.serve_tcp()
        link = connect(f"tcpout://127.0.0.1:{port}")
        try:
            await link.open(timeout=5.0)
            with link.subscribe("LOCAL_POSITION_NED") as sub:
                t0 = time.monotonic()
                ap.hang_up()
                with pytest.raises(LinkLost, match=f"tcp 127.0.0.1:{port}: the autopilot (closed|reset) the connection"):
                    await sub.next(5.0)
                assert time.monotonic() - t0 < 1.0
            t0 = time.monotonic()
            with pytest.raises(LinkLost):
                await link.arm()
            assert time.monotonic() - t0 < 0.5  # not three 1 s retries
            link.send_heartbeat()  # sending on a lost link drops the frame, never raises
        finally:
            link.close()
            ap.close()

    asyncio.run(main())


def test_a_tcp_link_waits_for_an_autopilot_that_is_not_listening_yet() -> None:
    """ArduPilot SITL opens SERIAL0 a moment after its process starts: connecting is
    retried within the open's bound, and a port nobody opens is a VehicleTimeout."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]

    async def main() -> None:
        link = connect(f"tcpout://127.0.0.1:{port}")
        opening = asyncio.create_task(link.open(timeout=10.0))
        await asyncio.sleep(1.2)
        assert not opening.done()
        server = await asyncio.start_server(_heartbeats, "127.0.0.1", port)
        try:
            await opening
            assert link.sysid == 1
        finally:
            link.close()
            server.close()
        nobody = connect(f"tcpout://127.0.0.1:{port}")
        with pytest.raises(VehicleTimeout, match="connection to the autopilot within 1 s"):
            await nobody.open(timeout=1.0)
        nobody.close()

    asyncio.run(main())


async def _heartbeats(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
    ap = ScriptedAutopilot()
    while not writer.is_closing():
        writer.write(ap.heartbeat())
        await asyncio.sleep(0.1)


@pytest.mark.parametrize("exc,code,line", [
    (UserError("bad flag"), EXIT_USER, "prog: error: bad flag"),
    (ExceptionGroup("task group", [UserError("far home")]), EXIT_USER, "prog: error: far home"),
    (ExceptionGroup("g", [ExceptionGroup("inner", [VehicleTimeout(1, "HOME_POSITION", 2.0)])]), EXIT_VEHICLE,
     "prog: error: vehicle 1: no HOME_POSITION within 2 s"),
    (CommandRejected(1, 22, 4, "MAV_RESULT_FAILED"), EXIT_VEHICLE, "prog: error: vehicle 1: command 22 rejected (MAV_RESULT_FAILED)"),
    (PermissionError(13, "Permission denied"), EXIT_SYSTEM, "prog: error: [Errno 13] Permission denied"),
    (KeyboardInterrupt(), EXIT_INTERRUPTED, "prog: interrupted"),
])
def test_run_reporting_makes_each_failure_one_line(exc: BaseException, code: int, line: str,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    def body() -> int:
        raise exc

    assert run_reporting("prog", body) == code
    assert capsys.readouterr().err == line + "\n"


def test_run_reporting_leaves_a_bug_its_traceback() -> None:
    def body() -> int:
        raise ExceptionGroup("g", [ZeroDivisionError("bug")])

    with pytest.raises(ExceptionGroup):
        run_reporting("prog", body)
    assert run_reporting("prog", lambda: None) == 0


def test_a_handled_subscription_gets_each_message_as_it_is_parsed() -> None:
    """`handle_with`: a lockstep agent answers each LOCAL_POSITION_NED in the link's receive
    callback; nothing is queued meanwhile, and queueing resumes once the handler is removed."""
    from plmarl_sitl.deploy.mavlink.client import VehicleLink
    from plmarl_sitl.deploy.mavlink.codec import Codec

    link = VehicleLink("127.0.0.1", 9, sysid=255)
    vehicle = Codec(1, 1)
    sub = link.subscribe("LOCAL_POSITION_NED")
    got: list[int] = []
    sub.handle_with(lambda m: got.append(m.time_boot_ms))
    two = b"".join(vehicle.encode(vehicle.mav.local_position_ned_encode(ms, 0, 0, -5, 0, 0, 0)) for ms in (100, 200))
    link.feed_datagram(two)
    assert got == [100, 200] and not sub.queued
    sub.handle_with(None)
    link.feed_datagram(vehicle.encode(vehicle.mav.local_position_ned_encode(300, 0, 0, -5, 0, 0, 0)))
    assert got == [100, 200] and [m.time_boot_ms for m in sub.queued] == [300]
