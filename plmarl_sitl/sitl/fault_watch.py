"""What a vehicle under an autopilot fault says and does, as events.

An autopilot fault (gps_loss, motor_failure) goes to the vehicle's own fault injection and
the vehicle flies on under its autopilot. From the fault on, every whole second, the world
records what changed since the last: its mode, whether it is armed, whether it still
streams a position, and what the vehicle itself reported (`WorldVehicles.fault_reports`:
the parameter echo, its STATUSTEXTs), each at the mission second it happened.
"""

from __future__ import annotations

from plmarl_sitl.sitl.start import MissionTime
from plmarl_sitl.sitl.vehicles import WorldVehicles


class FaultWatch:
    def __init__(self, vehicles: WorldVehicles, time: MissionTime) -> None:
        self.vehicles, self.time = vehicles, time
        self.faulted: dict[int, tuple[str, bool, bool]] = {}  # UAVs under a fault: last (mode, armed, position)

    def watch(self, i: int) -> None:
        """Vehicle i gets a fault now: its changes from here on are reported."""
        if i not in self.faulted:
            row = self.vehicles.uav_rows()[i]
            self.faulted[i] = (row["mode"], row["armed"], self.vehicles.position_streams(i))

    def reports(self, rows: list[dict]) -> list[dict]:
        """The "autopilot" events since the last second (`rows`: the vehicles' rows now)."""
        if self.time.t0 is None:
            return []
        reports = self.vehicles.fault_reports()
        for i, (mode, armed, streams) in self.faulted.items():
            now = (rows[i]["mode"], rows[i]["armed"], self.vehicles.position_streams(i))
            if now == (mode, armed, streams):
                continue
            self.faulted[i] = now
            change = {"mode": now[0]} if now[0] != mode else {}
            change |= {"armed": now[1]} if now[1] != armed else {}
            change |= {"position": "streaming" if now[2] else "stopped"} if now[2] != streams else {}
            reports.append({"uav": i, "boot_s": None, **change})
        entries = []
        for r in reports:
            i, boot_s = r.pop("uav"), r.pop("boot_s")
            t0 = self.time.t0_by_uav[i] if self.time.t0_by_uav is not None else self.time.t0
            t = (boot_s - t0) if boot_s is not None else (self.time.k or 0)  # None: seen at this second
            entries.append({"t": round(float(t), 2), "type": "autopilot", "uav": i, **r})
        return entries
