"""MAVSDK 4 (native binding) against the PX4 personality over real UDP, at 1x speed.

This is the scenario MAVSDK users run against PX4 SITL: connect, health, arm, takeoff,
acceleration setpoints in OFFBOARD, then stop streaming and watch the failsafe.
"""

from __future__ import annotations

import asyncio
import math
import time

import pytest
import torch
from aphelpers import run, running_host, wait_until
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.offboard import AccelerationNed, OffboardAsync
from mavsdk.asyncio.plugins.param import ParamAsync
from mavsdk.asyncio.plugins.telemetry import FlightMode, TelemetryAsync

pytestmark = [pytest.mark.integration, pytest.mark.timeout(90)]


def test_mavsdk_offboard_acceleration_and_loss_failsafe() -> None:
    run(_scenario())


async def _scenario() -> None:
    async with running_host(2, personality_name="px4") as host:
        cfg = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
        async with Mavsdk(cfg) as sdk:
            # Vehicle 2 (sysid 2) on its own port: nothing may latch onto vehicle 1.
            await sdk.add_any_connection(f"udpout://127.0.0.1:{host.ports[1]}")
            system = await sdk.first_autopilot(10.0)
            assert system is not None
            assert await system.get_system_id() == 2
            vehicle = host.vehicle(1)
            tel, act, off, par = TelemetryAsync(system), ActionAsync(system), OffboardAsync(system), ParamAsync(system)

            async with asyncio.timeout(10):
                async for health in tel.subscribe_health():
                    if health.is_local_position_ok and health.is_home_position_ok:
                        break

            assert await par.get_param_float("COM_OF_LOSS_T") == pytest.approx(1.0)
            # Setpoint loss: hold (5) instead of PX4's default 0, which without RC ends in RTL.
            await par.set_param_int("COM_OBL_RC_ACT", 5)
            assert vehicle.params["offboard_loss_action"] == 5
            await act.set_takeoff_altitude(8.0)  # writes MIS_TAKEOFF_ALT over the param protocol
            assert vehicle.params["takeoff_alt_m"] == pytest.approx(8.0)

            await act.arm()
            assert vehicle.armed
            await act.takeoff()
            await wait_until(lambda: vehicle.mode == "AUTO.LOITER", 25, "takeoff done")  # PX4: ~4 s spool-up, 1.5 m/s
            await asyncio.sleep(1.5)  # let the hold settle

            await tel.set_rate_position_velocity_ned(50.0)  # SET_MESSAGE_INTERVAL
            await off.set_acceleration_ned(AccelerationNed(0.0, 0.0, 0.0))
            await off.start()
            assert vehicle.mode == "OFFBOARD"

            # 2 s of 2 m/s^2 north, timed by telemetry so event-loop jitter does not count. PX4
            # feeds it forward and the airframe's drag (1 /s, SIH) slows it: 2 (1 - e^-2) m/s.
            await off.set_acceleration_ned(AccelerationNed(2.0, 0.0, 0.0))
            t_start = None
            async with asyncio.timeout(10):
                async for pv in tel.subscribe_position_velocity_ned():
                    now = time.monotonic()
                    vn = pv.velocity.north_m_s
                    if t_start is None and vn > 0.02:
                        t_start = now - vn / 2.0  # extrapolate back to when acceleration began
                    if t_start is not None and now - t_start >= 2.0:
                        break
            assert vn == pytest.approx(2.0 * (1 - math.exp(-2.0)), rel=0.08)

            await asyncio.sleep(4.0 - (time.monotonic() - t_start))
            assert await off.is_active()
            async with asyncio.timeout(3):
                async for mode in tel.subscribe_flight_mode():
                    assert mode == FlightMode.OFFBOARD
                    break

            # Stop the setpoint stream (the plugin's sender dies with it): failsafe to hold.
            off.destroy()
            t_lost = time.monotonic()
            async with asyncio.timeout(5):
                async for mode in tel.subscribe_flight_mode():
                    if mode != FlightMode.OFFBOARD:
                        break
            assert mode == FlightMode.HOLD
            assert time.monotonic() - t_lost <= 1.0 + 0.5
            assert vehicle.mode == "AUTO.LOITER"

            # ... and holds: brakes, settles on the hold point and stays there.
            target = vehicle.active_target()
            assert target is not None and target[0] == 0xDF8  # a position target
            hold = torch.tensor(target[1], dtype=torch.float64)

            def settled() -> bool:
                s = host.true_states()[1]
                return float(s[3:].norm()) < 0.2 and float((s[:3] - hold).norm()) < 0.5

            # Settled for 1.5 s on end: the brake overshoots the hold point once and turns back
            # (at the turn it is briefly at rest within 0.5 m).
            since = None
            async with asyncio.timeout(15):
                while since is None or time.monotonic() - since < 1.5:
                    if not settled():
                        since = None
                    elif since is None:
                        since = time.monotonic()
                    await asyncio.sleep(0.05)
            assert settled() and vehicle.mode == "AUTO.LOITER"
            assert host.vehicle(0).counters.messages == 0  # vehicle 1 was never talked to
            assert vehicle.counters.dropped == 0
