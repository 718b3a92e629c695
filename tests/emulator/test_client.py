"""The typed asyncio client (mavlink/client.py) against both personalities over UDP."""

from __future__ import annotations

import asyncio

import pytest
from aphelpers import run, running_host, wait_until

from plmarl_sitl.deploy.mavlink.client import VehicleLink
from plmarl_sitl.errors import CommandRejected

pytestmark = [pytest.mark.integration, pytest.mark.timeout(60)]


@pytest.mark.parametrize("personality,offboard", [("px4", "OFFBOARD"), ("ardupilot", "GUIDED")])
def test_client_flies_a_vehicle(personality: str, offboard: str) -> None:
    async def main() -> None:
        async with running_host(2, speedup=5.0, personality_name=personality) as host:
            v = host.vehicle(1)
            async with VehicleLink("127.0.0.1", host.ports[1]) as link:
                assert link.sysid == 2 and link.personality is not None and link.personality.name == personality
                if personality == "ardupilot":
                    await link.set_mode("GUIDED")
                await link.arm()
                await link.takeoff(15.0)
                await wait_until(lambda: abs(v.altitude() - 15.0) < 0.3 and not v.taking_off, 10, "takeoff")
                with pytest.raises(CommandRejected) as exc:
                    await link.disarm()
                # What each real autopilot answers a disarm in the air (ArduCopter 4.7: FAILED, measured).
                # PX4 SITL: TEMPORARILY_REJECTED, "Disarming denied: not landed" (issue 28, measured).
                refused = "MAV_RESULT_TEMPORARILY_REJECTED" if personality == "px4" else "MAV_RESULT_FAILED"
                assert exc.value.result_name == refused and exc.value.sysid == 2
                link.send_accel_ned(0.0, 0.0, 0.0)
                await link.set_mode(offboard)
                for _ in range(10):
                    link.send_velocity_ned(3.0, 0.0, 0.0)
                    await asyncio.sleep(0.05)
                await wait_until(lambda: abs(v.velocity()[0] - 3.0) < 0.1, 5, "velocity tracked")
                await link.set_message_interval("ATTITUDE", 0)
                name = "COM_OF_LOSS_T" if personality == "px4" else "GUID_TIMEOUT"
                assert await link.param_set(name, 2.0) == 2.0
                assert await link.param_get(name) == 2.0
                version = await link.request("AUTOPILOT_VERSION", 148)
                assert version.uid == 2
                await link.land()
                assert v.mode in ("AUTO.LAND", "LAND")

    run(main())
