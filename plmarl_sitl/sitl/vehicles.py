"""The vehicles a SITL world runs its mission on, as the world sees them.

Two kinds, one interface (`WorldVehicles`):

* `EmulatedVehicles`: the point-mass autopilot emulator hosted in the world's process
  (`AutopilotHost`). The world owns their clock and moves it (`advance`), so every vehicle
  shares one boot clock.
* `external.ExternalVehicles`: autopilots that run elsewhere (ArduCopter SITL processes,
  real drones behind a MAVLink router), each on a MAVLink link of the world's own. Each
  has a clock of its own; the world follows them (`owns_clock` False).

What the world needs of them: their clock, true positions in the mission frame, which are
alive, what each is doing (the metrics row and the start condition: armed, in the offboard
mode and at take-off altitude), node failure, and each vehicle's mission start t0 on its
own clock.

Autopilot faults (gps_loss, motor_failure) go to the autopilot's own fault injection,
ArduPilot SITL's SIM_ parameters (`GPS_OFF`, `GPS_ON`, `MOTOR_FAIL`): an external vehicle
gets a PARAM_SET on the world's link, and what it echoes in PARAM_VALUE is reported; the
emulator applies the same parameters' effect in-process (`AutopilotHost.set_gps`,
`fail_motor`), reproducing what the real one was measured to do. Either way the vehicle
flies on under its autopilot; `mark_failed` only stops counting it (coverage, relaying).
`fault_reports` hands the world what each vehicle said about it since the last call: the
parameter echo and the STATUSTEXTs of a vehicle under a fault, each at its boot time.
"""

from __future__ import annotations

from pathlib import Path
from typing import Protocol

import numpy as np
import torch

from plmarl_sitl.deploy.mavlink.personality import Behaviour
from plmarl_sitl.sitl.autopilot.host import AutopilotHost

# ArduPilot SITL's fault injection (libraries/SITL/SITL.cpp, SIM_GPS.cpp, AP_HAL_SITL/SITL_State.cpp):
# SIM_GPS1_ENABLE 0 takes the first GPS's fix away; SIM_ENGINE_FAIL is a mask of motor outputs
# whose thrust is multiplied by SIM_ENGINE_MUL (0: motor 1 stops).
GPS_OFF = (("SIM_GPS1_ENABLE", 0.0),)
GPS_ON = (("SIM_GPS1_ENABLE", 1.0),)
MOTOR_FAIL = (("SIM_ENGINE_MUL", 0.0), ("SIM_ENGINE_FAIL", 1.0))


class WorldVehicles(Protocol):
    owns_clock: bool  # True: the world moves the clock (`advance`); False: it follows `now`

    @property
    def n(self) -> int: ...
    @property
    def now(self) -> float:
        """The vehicles' clock, boot seconds (external: the slowest live one's, on a common reference)."""
        ...
    @property
    def started(self) -> bool: ...
    async def start(self) -> None: ...
    def close(self) -> None: ...
    def advance(self, dt_s: float) -> None: ...
    def positions(self) -> torch.Tensor:
        """(N, 3) float64 true positions in the mission frame."""
        ...
    def alive(self) -> torch.Tensor:
        """(N,) bool: not failed (external: also heard from lately)."""
        ...
    def kill(self, i: int) -> None: ...
    def set_gnss_noise(self, i: int, std_m: float) -> None: ...
    def set_gps(self, i: int, on: bool) -> None:
        """gps_loss: vehicle i's GPS goes dark (on=False) or comes back, through its autopilot."""
        ...
    def fail_motor(self, i: int) -> None:
        """motor_failure: one of vehicle i's motors stops, through its autopilot."""
        ...
    def mark_failed(self, i: int) -> None:
        """Stop counting vehicle i (no coverage, no relaying) without touching it."""
        ...
    def fault_reports(self) -> list[dict]:
        """What vehicles under a fault said since the last call: {"uav", "boot_s", and "param",
        "set", "echo" (None: unconfirmed), "via" | "text"}; boot_s on the vehicle's own clock."""
        ...
    def position_streams(self, i: int) -> bool:
        """Whether vehicle i's autopilot reports its position now (its EKF has one)."""
        ...
    def uav_rows(self) -> list[dict]:
        """Per UAV, for the metrics: id, pos, vel, alt, acc (the active setpoint), mode, armed, alive."""
        ...
    def not_ready(self, takeoff_alt_m: float) -> list[str]:
        """One entry per live vehicle not yet flying under its agent, saying why."""
        ...
    def start_times(self, t0: float) -> list[float] | None:
        """Mission start `t0` (on `now`'s clock) on each vehicle's own clock; None if they share `now`'s."""
        ...
    def record_tlogs(self, directory: Path) -> list[Path]: ...


class EmulatedVehicles:
    """The emulator's vehicles, hosted in this process (`host`): one shared clock, moved by the world."""

    owns_clock = True

    def __init__(self, host: AutopilotHost) -> None:
        self.host = host
        self.failed: set[int] = set()  # counted failed by an autopilot fault (flying on, or fallen)
        self._reports: list[dict] = []

    @property
    def n(self) -> int:
        return self.host.count

    @property
    def now(self) -> float:
        return self.host.now

    @property
    def started(self) -> bool:
        return self.host.started

    async def start(self) -> None:
        await self.host.start()

    def close(self) -> None:
        self.host.close()

    def advance(self, dt_s: float) -> None:
        self.host.advance(dt_s)

    def positions(self) -> torch.Tensor:
        return self.host.mission_positions()

    def alive(self) -> torch.Tensor:
        # from numpy: torch.tensor() of a list costs 3x more, and a lockstep world asks every substep
        return torch.from_numpy(np.array([not v.killed and v.index not in self.failed for v in self.host.vehicles]))

    def kill(self, i: int) -> None:
        self.host.kill(i)

    def set_gnss_noise(self, i: int, std_m: float) -> None:
        self.host.set_gnss_noise(i, std_m)

    def set_gps(self, i: int, on: bool) -> None:
        self.host.set_gps(i, on)
        self._applied(i, GPS_ON if on else GPS_OFF)

    def fail_motor(self, i: int) -> None:
        self.host.fail_motor(i)
        self._applied(i, MOTOR_FAIL)

    def _applied(self, i: int, params: tuple[tuple[str, float], ...]) -> None:
        v = self.host.vehicles[i]
        if v.texts is None:
            v.texts = []  # from now on its STATUSTEXTs are reported
        for name, value in params:
            self._reports.append({"uav": i, "boot_s": self.host.now, "param": name, "set": value, "echo": value,
                                  "via": "emulator, in-process"})

    def mark_failed(self, i: int) -> None:
        self.failed.add(i)

    def fault_reports(self) -> list[dict]:
        out, self._reports = self._reports, []
        for v in self.host.vehicles:
            if v.texts:
                out += [{"uav": v.index, "boot_s": t, "text": text} for t, text in v.texts]
                v.texts.clear()
        return sorted(out, key=lambda r: r["boot_s"])

    def position_streams(self, i: int) -> bool:
        v = self.host.vehicles[i]
        return not v.killed and not v.aiding_stopped and self.host.fleet.boot.position(self.host.now)

    def uav_rows(self) -> list[dict]:
        states = self.host.true_states()
        # One tensor op and one tolist for all vehicles (the same elementwise sums as row by row).
        positions = (states[:, :3] + self.host.home_offsets).tolist()
        velocities = states[:, 3:].tolist()
        rows = []
        for i, v in enumerate(self.host.vehicles):
            p = positions[i]
            rows.append({
                "id": i,
                "pos": [round(x, 2) for x in p],
                "vel": [round(x, 3) for x in velocities[i]],
                "alt": round(-p[2], 2),
                "acc": [round(x, 2) for x in v.last_accel()],  # the active setpoint: the agent's last action
                "mode": v.mode,
                "armed": v.armed,
                "alive": not v.killed and i not in self.failed,
            })
        return rows

    def not_ready(self, takeoff_alt_m: float) -> list[str]:
        out = []
        for v in self.host.vehicles:
            if v.killed:
                continue
            ok = v.armed and v.behaviour == Behaviour.OFFBOARD and not v.taking_off
            if not ok or v.altitude() < takeoff_alt_m - 1.0:
                out.append(f"{v.index} ({v.mode}, {'armed' if v.armed else 'disarmed'}, {v.altitude():.1f} m)")
        return out

    def start_times(self, t0: float) -> list[float] | None:
        return None

    def record_tlogs(self, directory: Path) -> list[Path]:
        return self.host.record_tlogs(directory)
