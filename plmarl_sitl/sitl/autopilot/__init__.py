"""Point-mass autopilot emulator: the vehicle side of MAVLink, PX4 or ArduPilot flavoured.

`AutopilotHost` hosts N vehicles in one asyncio process (the SITL world process owns the
clock and calls `advance`); `run_realtime` drives a host from wall time × speedup. Inside,
modules depend one way: host -> handlers -> telemetry -> vehicle -> fleet -> guidance, schedule.

Its names are imported on first use: `import plmarl_sitl.sitl.autopilot.boot` (the launcher
checks `--boot` before its fork server) must not import the host, and with it torch and the
world's modules, into the process every agent is forked from.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from plmarl_sitl.sitl.autopilot.host import AutopilotHost
    from plmarl_sitl.sitl.autopilot.runner import RunStats, run_realtime

_WHERE = {"AutopilotHost": "host", "RunStats": "runner", "run_realtime": "runner"}

__all__ = ["AutopilotHost", "RunStats", "run_realtime"]


def __getattr__(name: str) -> object:
    if name not in _WHERE:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{_WHERE[name]}"), name)
