"""100,000 random and mutated datagrams into one vehicle's UDP port.

Every datagram is bad in a way the test knows, so the per-vehicle counters must match the
input exactly; afterwards a real client (pymavlink) still gets heartbeats and command acks.
"""

from __future__ import annotations

import asyncio
import math
import random
import struct
from collections import Counter

import pytest
from aphelpers import run, running_host
from pymavlink import mavutil

from plmarl_sitl.deploy.mavlink.codec import Codec, dialect

pytestmark = [pytest.mark.integration, pytest.mark.timeout(120)]

N = 100_000
d = dialect


def _valid_frames(client: Codec, sysid: int) -> list[bytes]:
    m = client.mav
    msgs = [
        m.heartbeat_encode(6, 8, 0, 0, 0),
        m.command_long_encode(sysid, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0),
        m.command_long_encode(sysid, 1, 176, 0, 1, 6, 0, 0, 0, 0, 0),
        m.set_position_target_local_ned_encode(0, sysid, 1, 1, 0x0C3F, 0, 0, 0, 0, 0, 0, 1.5, -2.0, 0.5, 0, 0),
        m.param_request_list_encode(sysid, 1),
        m.param_set_encode(sysid, 1, b"COM_OF_LOSS_T", 1.0, 9),
        m.timesync_encode(0, 42),
        m.mission_request_list_encode(sysid, 1),
    ]
    return [client.encode(x) for x in msgs]


def _bad_setpoint(client: Codec, rng: random.Random, sysid: int) -> bytes:
    bad = rng.choice([math.nan, math.inf, -math.inf, 1e9])
    acc = [0.0, 0.0, 0.0]
    acc[rng.randrange(3)] = bad
    kind = rng.randrange(3)
    if kind == 0:
        msg = client.mav.set_position_target_local_ned_encode(0, sysid, 1, 1, 0x0C3F, 0, 0, 0, 0, 0, 0, *acc, 0, 0)
    elif kind == 1:  # FORCE_SET is rejected
        msg = client.mav.set_position_target_local_ned_encode(0, sysid, 1, 1, 0x0C3F | 0x200, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0, 0)
    else:  # unsupported frame (BODY_NED)
        msg = client.mav.set_position_target_local_ned_encode(0, sysid, 1, 8, 0x0C3F, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0, 0)
    return client.encode(msg)


def _unknown_msgid(rng: random.Random) -> bytes:
    payload = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 40)))
    msgid = rng.randrange(200_000, 1 << 24)
    hdr = struct.pack("<BBBBBBBHB", 0xFD, len(payload), 0, 0, 0, 255, 190, msgid & 0xFFFF, msgid >> 16)
    return hdr + payload + b"\0\0"


def make_fuzz(seed: int, sysid: int) -> tuple[list[bytes], Counter]:
    """(datagrams, expected fault counts). 'any' are bad but of no predictable category."""
    rng = random.Random(seed)
    client = Codec(255, 190)
    frames = _valid_frames(client, sysid)
    out: list[bytes] = []
    expect: Counter = Counter()
    no_marker = [b for b in range(256) if b not in (0xFD, 0xFE)]
    for _ in range(N):
        r = rng.random()
        f = rng.choice(frames)
        if r < 0.2:  # garbage without any frame marker
            out.append(bytes(rng.choice(no_marker) for _ in range(rng.randrange(1, 300))))
            expect["garbage"] += 1
        elif r < 0.4:  # a burst of <= 16 bits flipped in payload/CRC: CRC-16 catches all
            b = bytearray(f)
            pos = rng.randrange(10, len(b) - 1)
            b[pos] ^= rng.randrange(1, 256)
            b[pos + 1] ^= rng.randrange(256)
            out.append(bytes(b))
            expect["bad_crc"] += 1
        elif r < 0.55:  # cut short, or the length byte inflated past the datagram's end
            if rng.random() < 0.5:
                out.append(f[: rng.randrange(1, len(f))])
            else:
                b = bytearray(f)
                b[1] = min(255, b[1] + rng.randrange(3, 100))
                out.append(bytes(b))
            expect["truncated"] += 1
        elif r < 0.7:
            out.append(_bad_setpoint(client, rng, sysid))
            expect["bad_value"] += 1
        elif r < 0.8:
            out.append(_unknown_msgid(rng))
            expect["unknown_msg"] += 1
        else:  # anything at all
            out.append(bytes(rng.randrange(256) for _ in range(rng.randrange(1, 300))))
            expect["any"] += 1
    return out, expect


def _client_checks(port: int, sysid: int) -> tuple[int, int]:
    m = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255)
    m.mav.heartbeat_send(6, 8, 0, 0, 0)
    hb = m.wait_heartbeat(timeout=5)
    assert hb is not None and m.target_system == sysid
    m.mav.command_long_send(sysid, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
    ack = m.recv_match(type="COMMAND_ACK", blocking=True, timeout=5)
    m.close()
    return ack.command, ack.result


class _Sink(asyncio.DatagramProtocol):
    """The fuzzer's socket: telemetry sent back to it is read and ignored."""


def test_fuzz_100k_datagrams() -> None:
    async def scenario():
        async with running_host(2, personality_name="px4") as host:
            v = host.vehicle(1)
            data, expect = make_fuzz(seed=4, sysid=v.sysid)
            loop = asyncio.get_running_loop()
            tx, _ = await loop.create_datagram_endpoint(_Sink, remote_addr=("127.0.0.1", host.ports[1]))
            try:
                for start in range(0, N, 200):
                    for dg in data[start : start + 200]:
                        tx.sendto(dg)
                    # Pace the sender so the kernel never drops: the counts must be exact.
                    async with asyncio.timeout(10):
                        while v.counters.datagrams < min(start + 200, N):
                            await asyncio.sleep(0)
            finally:
                tx.close()
            counters = v.counters.as_dict()
            ack = await asyncio.to_thread(_client_checks, host.ports[1], v.sysid)
            return counters, expect, ack, host.vehicle(0).counters.datagrams

    result = {}

    async def main():
        result["r"] = await scenario()

    run(main())
    c, expect, ack, other = result["r"]
    assert c["datagrams"] >= N
    dropped = sum(c[k] for k in ("garbage", "truncated", "bad_header", "bad_crc", "unknown_msg", "bad_value"))
    assert dropped == N  # every bad datagram counted exactly once, none let through
    for k in ("garbage", "truncated", "bad_crc", "unknown_msg", "bad_value"):
        assert c[k] >= expect[k]
    # The 'any' datagrams land in some category; the deliberate ones are exact lower bounds
    # and together with 'any' they add up.
    assert sum(c[k] - expect[k] for k in ("garbage", "truncated", "bad_header", "bad_crc", "unknown_msg")) == expect["any"]
    assert c["bad_value"] == expect["bad_value"]
    assert ack == (400, d.MAV_RESULT_ACCEPTED)
    assert other == 0
