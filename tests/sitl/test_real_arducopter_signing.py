"""MAVLink signing against a REAL ArduCopter SITL: set ARDUCOPTER to the `arducopter`
binary; without it this test skips.

The launcher's own code provisions the key (`ArduCopterFleet.provision_signing`:
SETUP_SIGNING on SERIAL0, ArduPilot's always-trusted channel 0). Then, on SERIAL1 (a
channel that enforces signing, like a telemetry radio), an unsigned client and one with a
wrong key are ignored (no COMMAND_ACK, the mode unchanged) although they still read the
vehicle's heartbeats, and a client with the key changes the mode.
"""

from __future__ import annotations

import asyncio
import dataclasses
import os
import time
from pathlib import Path

import pytest

from plmarl_sitl.mission import load_mission
from plmarl_sitl.sitl.arducopter import ArduCopterFleet, find_copter_parm, instance_free

os.environ.setdefault("MAVLINK20", "1")  # before pymavlink's mavutil is imported
from pymavlink import mavutil  # noqa: E402

BINARY = os.environ.get("ARDUCOPTER", "")
pytestmark = [
    pytest.mark.integration,
    pytest.mark.slow,
    pytest.mark.timeout(180),
    pytest.mark.skipif(not BINARY, reason="set ARDUCOPTER=/path/to/arducopter (a real ArduCopter SITL binary) to run"),
]
ROOT = Path(__file__).resolve().parents[2]
INSTANCES = range(70, 80)
KEY = bytes(range(1, 33))
WRONG = bytes(range(2, 34))
STABILIZE, ALT_HOLD, LOITER = 0, 2, 5
mav = mavutil.mavlink


def _try_mode(port: int, key: bytes | None, sysid: int, mode: int) -> dict:
    """Connect to SERIAL1 as `sysid` (signing with `key`), read a heartbeat, ask for `mode`."""
    m = mavutil.mavlink_connection(f"tcp:127.0.0.1:{port}", source_system=sysid, source_component=190)
    try:
        if key is not None:
            # Heartbeats shown unverified, as a ground station with the wrong key would (the right key verifies them).
            m.setup_signing(key, sign_outgoing=True, allow_unsigned_callback=lambda _m, msgid: msgid == 0)
        hb = m.recv_match(type="HEARTBEAT", blocking=True, timeout=10, condition="HEARTBEAT.get_srcSystem() == 1")
        signed = hb is not None and bool(hb.get_header().incompat_flags & mav.MAVLINK_IFLAG_SIGNED)
        ack = None
        for _ in range(3):
            m.mav.command_long_send(1, 1, mav.MAV_CMD_DO_SET_MODE, 0, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, mode,
                                    0, 0, 0, 0, 0)
            ack = m.recv_match(type="COMMAND_ACK", blocking=True, timeout=1.5)
            if ack is not None:
                break
        time.sleep(0.5)
        last = m.recv_match(type="HEARTBEAT", blocking=True, timeout=3, condition="HEARTBEAT.get_srcSystem() == 1")
        return {"heartbeat": hb is not None, "signed": signed, "ack": None if ack is None else ack.result,
                "mode": None if last is None else last.custom_mode}
    finally:
        m.close()


def test_unsigned_and_wrongly_signed_commands_are_ignored_signed_ones_work(tmp_path):
    base = next((i for i in INSTANCES if instance_free(i)), None)
    if base is None:
        pytest.skip(f"no free ArduPilot SITL instance in -I {INSTANCES.start}..{INSTANCES.stop - 1}")
    mission = dataclasses.replace(load_mission(ROOT / "missions" / "paper_urban.yaml"), n_uavs=1)
    binary = Path(BINARY)
    fleet = ArduCopterFleet(binary, find_copter_parm(binary), mission, 1.0, tmp_path, base)
    results = {}

    async def main():
        fleet.start()
        try:
            await fleet.wait_listening()
            t = time.perf_counter()
            await fleet.provision_signing([KEY])
            results["provision_s"] = time.perf_counter() - t
            port = fleet.procs[0].serial1
            for name, key, sysid in (("unsigned", None, 250), ("wrong_key", WRONG, 251), ("signed", KEY, 252)):
                results[name] = await asyncio.to_thread(_try_mode, port, key, sysid, ALT_HOLD)
        finally:
            await fleet.stop()

    asyncio.run(main())
    print(results)
    assert (tmp_path / "arducopter" / "vehicle0" / "eeprom.bin").exists()  # where ArduPilot keeps the key
    for name in ("unsigned", "wrong_key"):
        r = results[name]
        assert r["heartbeat"] and r["signed"], f"{name}: the vehicle must still be seen, signing"
        assert r["ack"] is None and r["mode"] == STABILIZE, f"{name}: a command without the key acted: {r}"
    r = results["signed"]
    assert r["ack"] == mav.MAV_RESULT_ACCEPTED and r["mode"] == ALT_HOLD, r
