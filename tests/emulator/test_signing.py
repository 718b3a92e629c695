"""MAVLink 2 signing: with a key, only well-signed commands and setpoints act.

Unsigned and badly signed ones are dropped and counted per category; the vehicle's own
(signed) heartbeats keep flowing to everyone, and unsigned heartbeats from a ground
station are still accepted so it is seen as a peer.
"""

from __future__ import annotations

import asyncio

import pytest
from aphelpers import run, running_host
from pymavlink import mavutil

pytestmark = [pytest.mark.integration, pytest.mark.timeout(60)]

KEY = bytes(range(32))
WRONG = bytes(32)


def _client(port: int, key: bytes | None, source_system: int) -> mavutil.mavfile:
    m = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=source_system)
    if key is not None:
        # A client with the wrong key cannot verify the vehicle either; like a GCS would, it
        # chooses to show unverified heartbeats.
        hb_only = (lambda _mav, msgid: msgid == 0) if key != KEY else None
        m.setup_signing(key, sign_outgoing=True, allow_unsigned_callback=hb_only)
    return m


def _arm_attempt(m: mavutil.mavfile) -> int | None:
    m.mav.heartbeat_send(6, 8, 0, 0, 0)
    hb = m.wait_heartbeat(timeout=5)
    assert hb is not None, "heartbeats must flow whatever the key"
    m.mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
    m.mav.set_position_target_local_ned_send(0, 1, 1, 1, 0x0C3F, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0, 0)
    ack = m.recv_match(type="COMMAND_ACK", blocking=True, timeout=1.5)
    return None if ack is None else ack.result


def _scenario_clients(port: int) -> dict:
    out = {}
    for name, key, sysid in (("unsigned", None, 250), ("wrong_key", WRONG, 251), ("good", KEY, 252)):
        m = _client(port, key, sysid)
        out[name] = _arm_attempt(m)
        m.close()
    return out


def test_signing_rejects_unsigned_and_bad_signatures() -> None:
    result = {}

    async def main():
        async with running_host(1, personality_name="px4", signing_key=KEY) as host:
            out = await asyncio.to_thread(_scenario_clients, host.ports[0])
            result.update(out, counters=host.vehicle(0).counters, armed=host.vehicle(0).armed)

    run(main())
    assert result["unsigned"] is None and result["wrong_key"] is None
    assert result["good"] == mavutil.mavlink.MAV_RESULT_ACCEPTED and result["armed"]
    c = result["counters"]
    assert c.unsigned == 2  # the command and the setpoint of the unsigned client
    # Wrong key: its heartbeat is allowed unsigned, its command and setpoint are not.
    assert c.bad_signature == 2
    assert c.bad_value == 0
