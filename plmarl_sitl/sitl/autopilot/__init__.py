"""Point-mass autopilot emulator: the vehicle side of MAVLink, PX4 or ArduPilot flavoured.

`AutopilotHost` hosts N vehicles in one asyncio process (the SITL world process owns the
clock and calls `advance`); `run_realtime` drives a host from wall time × speedup. Inside,
modules depend one way: host -> handlers -> telemetry -> vehicle -> fleet -> guidance, schedule.
"""

from plmarl_sitl.sitl.autopilot.host import AutopilotHost
from plmarl_sitl.sitl.autopilot.runner import RunStats, run_realtime

__all__ = ["AutopilotHost", "RunStats", "run_realtime"]
