"""MAVLink 2 signing: with a key, only well-signed commands and setpoints act.

Unsigned and badly signed input (a wrong key, a replay) is dropped and counted per
category, with nothing but the personality's radio reports let through unsigned (ArduPilot
GCS_Signing.cpp, PX4 mavlink_sign_control.cpp: not even a ground station's HEARTBEAT).
The vehicle's own signed heartbeats and telemetry keep flowing to whoever speaks to it,
readable without the key. Real UDP sockets, real pymavlink clients, the agent's own client.
"""

from __future__ import annotations

import asyncio

import pytest
from aphelpers import run, running_host, wait_until
from pymavlink import mavutil

from plmarl_sitl.deploy.mavlink.client import VehicleLink
from plmarl_sitl.deploy.mavlink.codec import Codec, signing_timestamp
from plmarl_sitl.errors import VehicleTimeout

pytestmark = [pytest.mark.integration, pytest.mark.timeout(60)]

mav = mavutil.mavlink
KEY = bytes(range(32))
WRONG = bytes(32)
ATTACKS = 50  # of each kind: 100 % of them must be rejected and counted


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


@pytest.mark.parametrize("personality", ["px4", "ardupilot"])
def test_signing_rejects_unsigned_and_bad_signatures(personality: str) -> None:
    result = {}

    async def main():
        async with running_host(1, personality_name=personality, signing_key=KEY) as host:
            out = await asyncio.to_thread(_scenario_clients, host.ports[0])
            result.update(out, counters=host.vehicle(0).counters, armed=host.vehicle(0).armed)

    run(main())
    assert result["unsigned"] is None and result["wrong_key"] is None
    assert result["good"] == mav.MAV_RESULT_ACCEPTED and result["armed"]
    c = result["counters"]
    # Neither autopilot takes a ground station's heartbeat unsigned: heartbeat, command, setpoint.
    assert c.unsigned == 3
    assert c.bad_signature == 3
    assert c.bad_value == 0


def _attack(port: int, recorded: list[bytes]) -> dict:
    """An attacker without the key, on the vehicle's port: disarm, mode changes, setpoints,
    the legacy SET_MODE, and replays of the agent's own signed frames. It must still see
    the vehicle's heartbeats (signed, readable without the key)."""
    m = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255, source_component=190)
    m.mav.heartbeat_send(6, 8, 0, 0, 0)
    hb = m.recv_match(type="HEARTBEAT", blocking=True, timeout=5)
    for i in range(ATTACKS):
        m.mav.command_long_send(1, 1, mav.MAV_CMD_COMPONENT_ARM_DISARM, i % 256, 0, 21196, 0, 0, 0, 0, 0)
        m.mav.command_long_send(1, 1, mav.MAV_CMD_DO_SET_MODE, 0, 1, 9, 0, 0, 0, 0, 0)  # LAND
        m.mav.set_position_target_local_ned_send(0, 1, 1, mav.MAV_FRAME_LOCAL_NED, 0x0DF8,
                                                 500.0, -500.0, -90.0, 0, 0, 0, 0, 0, 0, 0, 0)
        m.mav.set_mode_send(1, 1, 6)  # RTL
        if i < len(recorded):
            m.write(recorded[i])  # a genuine signed setpoint, replayed
    ack = m.recv_match(type="COMMAND_ACK", blocking=True, timeout=1.0)
    m.close()
    return {"heartbeat": hb, "ack": ack}


def test_signed_agent_flies_and_an_unsigned_attacker_changes_nothing() -> None:
    """ArduPilot personality: the agent's signed link flies the vehicle in GUIDED; an
    attacker's unsigned disarm, LAND, RTL and setpoints, and replays of the agent's own
    frames, are all dropped and counted; armed, mode and target are unchanged."""
    out = {}

    async def main():
        async with running_host(1, personality_name="ardupilot", signing_key=KEY) as host:
            v = host.vehicle(0)
            link = VehicleLink("127.0.0.1", host.ports[0], signing_key=KEY)
            recorded: list[bytes] = []
            link.tlog = _Recorder(recorded)  # the agent's outgoing frames, as an eavesdropper would
            await link.open()
            await link.set_mode("GUIDED")
            await link.arm()
            await link.takeoff(5.0)
            await wait_until(lambda: v.altitude() > 4.5 and not v.taking_off, 20, "takeoff")
            for _ in range(ATTACKS):
                link.send_position_ned(10.0, 0.0, -5.0)
                await asyncio.sleep(0.005)
            await asyncio.sleep(0.2)
            before = (v.armed, v.mode, v.setpoint, dict(v.counters.as_dict()))
            # The agent's (sysid 255) SET_POSITION_TARGET_LOCAL_NED (id 84) frames.
            frames = [f for f in recorded if f[5] == 255 and f[7:10] == bytes((84, 0, 0))]
            res = await asyncio.to_thread(_attack, host.ports[0], frames[-ATTACKS:])
            await asyncio.sleep(0.3)
            out.update(before=before, after=(v.armed, v.mode, v.setpoint), counters=v.counters.as_dict(),
                       replays=len(frames[-ATTACKS:]), **res)
            link.send_position_ned(20.0, 0.0, -5.0)  # the agent still commands it
            await wait_until(lambda: v.setpoint is not None and v.setpoint[1][0] == 20.0, 5, "agent setpoint")
            link.close()

    run(main())
    armed, mode, setpoint, c0 = out["before"]
    assert armed and mode == "GUIDED" and setpoint[1] == (10.0, 0.0, -5.0)
    assert out["after"] == (armed, mode, setpoint), "the attack changed the vehicle's state"
    assert out["heartbeat"] is not None, "an unsigned ground station must still see the vehicle"
    assert out["ack"] is None  # nothing it sent was even answered
    c = out["counters"]
    # 1 heartbeat + 50 x (disarm, mode, setpoint, SET_MODE), every one counted; each replay too.
    assert c["unsigned"] - c0["unsigned"] == 1 + 4 * ATTACKS
    assert out["replays"] == ATTACKS
    assert c["bad_signature"] - c0["bad_signature"] == ATTACKS
    assert c["bad_value"] == 0


class _Recorder:
    """A .tlog stand-in that keeps each frame the link sends or receives."""

    def __init__(self, frames: list[bytes]) -> None:
        self.frames = frames

    def write(self, data: bytes) -> None:
        self.frames.append(bytes(data[8:]))


def test_a_forged_frame_with_a_huge_timestamp_does_not_cut_the_genuine_sender_off() -> None:
    """pymavlink records a stream's timestamp before it checks the signature; the codec
    checks the signature first, as the C library does. Otherwise one forged frame with the
    agent's ids and a timestamp near 2^48 would make every later genuine frame "old"."""
    vehicle = Codec(1, 1, KEY)
    agent = Codec(255, 190, KEY)
    forger = Codec(255, 190, WRONG)
    forger.mav.signing.timestamp = 2**48 - 10
    forged = forger.encode(forger.mav.command_long_encode(1, 1, 400, 0, 0, 21196, 0, 0, 0, 0, 0))
    assert vehicle.decode_datagram(forged).fault == "bad_signature"
    genuine = agent.encode(agent.mav.command_long_encode(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0))
    assert vehicle.decode_datagram(genuine).fault is None
    assert vehicle.decode_datagram(genuine).fault == "bad_signature"  # the same frame again: a replay


def test_new_stream_must_be_recent_and_timestamps_follow_the_clock() -> None:
    vehicle = Codec(1, 1, KEY)
    old = Codec(255, 190, KEY)
    old.mav.signing.timestamp = signing_timestamp() - 61 * 100_000
    old.mav.signing.sign_outgoing = False  # keep the stale timestamp: pack it by hand
    msg = old.mav.heartbeat_encode(6, 8, 0, 0, 0)
    old.mav.signing.sign_outgoing = True
    frame = msg.pack(old.mav)
    assert vehicle.decode_datagram(frame).fault == "bad_signature"  # a new stream > 60 s behind
    fresh = Codec(255, 190, KEY)
    fresh.mav.signing.timestamp = 0  # however it started, encode signs at the clock
    assert vehicle.decode_datagram(fresh.encode(fresh.mav.heartbeat_encode(6, 8, 0, 0, 0))).fault is None


def test_radio_status_is_accepted_unsigned_as_on_ardupilot() -> None:
    out = {}

    async def main():
        async with running_host(1, personality_name="ardupilot", signing_key=KEY) as host:
            def send() -> None:
                m = mavutil.mavlink_connection(f"udpout:127.0.0.1:{host.ports[0]}", source_system=51, source_component=68)
                m.mav.radio_status_send(200, 190, 90, 10, 10, 0, 0)
                m.mav.heartbeat_send(6, 8, 0, 0, 0)
                m.close()

            await asyncio.to_thread(send)
            await wait_until(lambda: host.vehicle(0).counters.datagrams >= 2, 5, "datagrams")
            out.update(host.vehicle(0).counters.as_dict())

    run(main())
    assert out["messages"] == 1 and out["unsigned"] == 1  # RADIO_STATUS taken, the HEARTBEAT not


def test_setup_signing_provisions_an_unsigned_vehicle_and_is_refused_armed() -> None:
    """SETUP_SIGNING (ArduPilot personality): takes effect at once; refused while armed with
    ArduPilot's STATUSTEXT; a zero key and timestamp turns signing off again (only signed,
    once a key is set)."""
    out: dict = {}

    async def main():
        async with running_host(1, personality_name="ardupilot") as host:
            v = host.vehicle(0)
            link = VehicleLink("127.0.0.1", host.ports[0])
            await link.open()
            texts = link.subscribe("STATUSTEXT", lambda m: "signing" in m.text)
            await link.set_mode("GUIDED")
            await link.arm()
            link.send(link.codec.mav.setup_signing_encode(1, 1, list(KEY), signing_timestamp()))
            out["armed_text"] = (await texts.next(2.0)).text
            out["signed_while_armed"] = v.codec.signing
            await link.disarm(force=True)
            link.send(link.codec.mav.setup_signing_encode(1, 1, list(KEY), signing_timestamp()))
            await wait_until(lambda: v.codec.signing, 2, "key set")
            try:  # the unsigned client is now ignored
                await link.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1.0, timeout=0.3, retries=1)
                out["unsigned_after"] = "accepted"
            except VehicleTimeout:
                out["unsigned_after"] = "ignored"
            link.close()
            signed = VehicleLink("127.0.0.1", host.ports[0], signing_key=KEY)
            await signed.open()
            await signed.arm()
            out["signed_armed"] = v.armed
            await signed.disarm(force=True)
            signed.send(signed.codec.mav.setup_signing_encode(1, 1, [0] * 32, 0))
            await wait_until(lambda: not v.codec.signing, 2, "signing off")
            signed.close()

    run(main())
    assert out["armed_text"] == "ERROR: Won't setup signing when armed" and not out["signed_while_armed"]
    assert out["unsigned_after"] == "ignored" and out["signed_armed"]


def test_per_vehicle_keys() -> None:
    """Vehicle i takes only key i: one agent's key does not command another vehicle."""
    keys = [bytes([i + 1]) * 32 for i in range(2)]
    out = {}

    async def main():
        async with running_host(2, personality_name="px4", signing_keys=keys) as host:
            for i in range(2):
                link = VehicleLink("127.0.0.1", host.ports[1 - i], signing_key=keys[i])
                try:
                    await link.open(timeout=1.5)
                    out[i] = "opened"
                except VehicleTimeout:
                    out[i] = "no heartbeat"  # it cannot verify the other vehicle's either
                link.close()
            out["bad"] = [host.vehicle(j).counters.bad_signature for j in range(2)]

    run(main())
    assert out[0] == out[1] == "no heartbeat"
    assert all(n > 0 for n in out["bad"])
