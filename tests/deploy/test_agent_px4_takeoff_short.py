"""The agent's take-off against a PX4 that ends AUTO.TAKEOFF short of the height the agent
reads (session 24, seen on real PX4 SIH in `test_gps_loss_and_motor_failure_go_through_px4s_own_failure_injection`).

What the real one did (its .tlog): the agent read HOME_POSITION before arming (altitude
487.511 m, z 0) and sent NAV_TAKEOFF to 487.511 + 60 m AMSL; PX4 set its home again at
arming (488.170 m, z 0.357: one noisy GPS fix), ended AUTO.TAKEOFF within NAV_MC_ALT_RAD of
the target on its own estimate, and held AUTO.LOITER at z -58.58 for minutes, 58.6 m above
the home the agent had read. The agent waited for 59 m until its bound and the swarm failed.

A scripted PX4 peer on a real UDP socket (`ScriptedAutopilot` with PX4's heartbeat and
modes) replays that: a climb that ends in AUTO.LOITER 58.6 m up. The emulator cannot show it (its home
has no GPS noise, and its PX4 loiters at the take-off setpoint)."""

from __future__ import annotations

import asyncio
import contextlib
import time
from pathlib import Path

import pytest

from plmarl_sitl.deploy.mavlink.codec import dialect
from plmarl_sitl.deploy.mavlink.personality import PX4
from plmarl_sitl.mission import load_mission

from .agent_process import agent_argv, run_agent, stop_at
from .conftest import MISSION
from .scripted_autopilot import ScriptedAutopilot

pytestmark = [pytest.mark.integration, pytest.mark.timeout(90)]

d = dialect
SPEEDUP = 10.0  # vehicle seconds per wall second
HELD_M = 58.6  # where the real PX4 held, above the home the agent had read
CLIMB_MPS = 3.0  # PX4 MPC_TKO_SPEED's order


class ScriptedPX4(ScriptedAutopilot):
    """PX4 as the agent sees it over UDP during start-up and take-off: PX4's heartbeat and
    modes, every command acknowledged and HOME_POSITION on request (`ScriptedAutopilot`),
    LOCAL_POSITION_NED at 10 Hz of vehicle time. NAV_TAKEOFF switches to AUTO.TAKEOFF and
    climbs; at HELD_M it ends AUTO.TAKEOFF in AUTO.LOITER and holds there."""

    def __init__(self, home: tuple[float, float, float]) -> None:
        super().__init__(home=home)
        self.mode = PX4.mode(PX4.boot_mode)
        self.armed = False
        self.z = 0.0
        self.climbing = False
        self.modes_seen: list[str] = [self.mode.name]
        self.t0 = time.monotonic()
        self.task: asyncio.Task | None = None
        self._applied = 0  # how many of `commands` the state has taken

    def set_mode(self, name: str) -> None:
        self.mode = PX4.mode(name)
        self.modes_seen.append(name)

    def heartbeat(self) -> bytes:
        base = PX4.base_mode_flags if self.mode.base_flags is None else self.mode.base_flags
        if self.armed:
            base |= d.MAV_MODE_FLAG_SAFETY_ARMED
        status = d.MAV_STATE_ACTIVE if self.armed else d.MAV_STATE_STANDBY
        return self.codec.encode(self.codec.mav.heartbeat_encode(
            d.MAV_TYPE_QUADROTOR, d.MAV_AUTOPILOT_PX4, base, self.mode.custom_mode, status, 3))

    def answers(self, data: bytes, mav) -> list[bytes]:  # noqa: ANN001 - pymavlink's parser
        out = super().answers(data, mav)  # acknowledges and records each command
        for command, params in self.commands[self._applied:]:
            if command == d.MAV_CMD_COMPONENT_ARM_DISARM:
                self.armed = params[0] == 1.0
            elif command == d.MAV_CMD_NAV_TAKEOFF and self.armed:
                self.set_mode("AUTO.TAKEOFF")
                self.climbing = True
            elif command == d.MAV_CMD_DO_SET_MODE:
                self.set_mode(PX4.mode_name(PX4.custom_mode_from_set_mode(params[1], params[2])))
        self._applied = len(self.commands)
        return out

    async def fly(self) -> None:
        dt = 0.1  # vehicle seconds per sample
        beat = 0
        while True:
            await asyncio.sleep(dt / SPEEDUP)
            vz = 0.0
            if self.climbing:
                vz = -CLIMB_MPS
                self.z = max(self.z + vz * dt, -HELD_M)
                if self.z <= -HELD_M:  # "Takeoff complete": PX4 holds where its take-off ended
                    self.climbing, vz = False, 0.0
                    self.set_mode("AUTO.LOITER")
            if self._udp is None or self.addr is None:
                continue
            boot_ms = int((time.monotonic() - self.t0) * SPEEDUP * 1000)
            self._udp.sendto(self.codec.encode(self.codec.mav.local_position_ned_encode(boot_ms, 0.0, 0.0, self.z, 0.0, 0.0, vz)),
                             self.addr)
            beat += 1
            if beat % 10 == 0:  # 1 Hz of vehicle time, as PX4
                self._udp.sendto(self.heartbeat(), self.addr)

    async def serve(self) -> int:
        port = await self.serve_udp()
        self.task = asyncio.create_task(self.fly())
        return port

    def close(self) -> None:
        if self.task is not None:
            self.task.cancel()
        super().close()


def test_px4_ending_its_takeoff_short_of_the_agents_band_hands_over_to_offboard(policy_dir: Path) -> None:
    """PX4 says the take-off is over (AUTO.TAKEOFF, then AUTO.LOITER) 58.6 m above the home
    the agent read, below its own 59 m band: the agent takes PX4's word and switches to
    OFFBOARD there, instead of waiting out its bound."""
    o = load_mission(MISSION).origin

    async def main():  # noqa: ANN202
        ap = ScriptedPX4((o.lat_deg, o.lon_deg, o.alt_m))
        port = await ap.serve()
        try:
            run = await run_agent(agent_argv(f"udpout://127.0.0.1:{port}", "mqtt://127.0.0.1:1", "--policy", str(policy_dir)),
                                  on_line=stop_at("in OFFBOARD"), timeout_s=60.0)
        finally:
            ap.close()
            with contextlib.suppress(asyncio.CancelledError):
                if ap.task is not None:
                    await ap.task
        return run, ap.modes_seen

    run, modes = asyncio.run(main())
    assert "px4 personality" in run.err, run.err
    assert "taking off to 60 m above home" in run.err, run.err
    # boot, take-off, PX4's own end of it, the agent's switch, and its stop (Ctrl-C: hold)
    assert modes == ["AUTO.LOITER", "AUTO.TAKEOFF", "AUTO.LOITER", "OFFBOARD", "AUTO.LOITER"], modes
    assert "in OFFBOARD at 58.6 m above home" in run.err, run.err
    assert "no takeoff" not in run.err, run.err
