"""Shared helpers: hosts on free UDP ports, driven by the real-time runner."""

from __future__ import annotations

import asyncio
import contextlib
import os
import random
from collections.abc import AsyncIterator

import pytest

from plmarl_sitl.sitl.autopilot import AutopilotHost, run_realtime

os.environ.setdefault("MAVLINK20", "1")  # pymavlink's mavutil reads this at import


@contextlib.asynccontextmanager
async def running_host(count: int = 1, speedup: float = 1.0, **kwargs) -> AsyncIterator[AutopilotHost]:
    """A started host on a random free port range, clocked at `speedup` until exit."""
    for _ in range(50):
        base = random.randrange(20000, 60000 - count)
        host = AutopilotHost(count, base_port=base, **kwargs)
        try:
            await host.start()
        except OSError:
            continue
        break
    else:
        pytest.fail("no free UDP port range")
    stop = asyncio.Event()
    task = asyncio.create_task(run_realtime(host, speedup, stop=stop), name="autopilot-clock")
    try:
        yield host
    finally:
        stop.set()
        await task
        host.close()


async def wait_until(pred, timeout: float, what: str, poll: float = 0.02) -> None:
    async with asyncio.timeout(timeout):
        while not pred():
            await asyncio.sleep(poll)


def run(coro) -> None:
    """Run an async test body (the suite does not depend on an asyncio pytest plugin)."""
    asyncio.run(coro)
