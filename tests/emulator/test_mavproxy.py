"""MAVProxy (from PyPI), run non-interactively: connects, loads the parameters, arms."""

from __future__ import annotations

import asyncio
import importlib.util
import sys

import pytest
from aphelpers import run, running_host, wait_until

pytestmark = [pytest.mark.integration, pytest.mark.timeout(90)]


def test_mavproxy_connects_loads_params_and_arms(tmp_path) -> None:
    # Run MAVProxy as a module of this interpreter: the `mavproxy.py` found on PATH may be a
    # shell shim (pyenv) or belong to another Python (a venv with system site packages).
    if importlib.util.find_spec("MAVProxy") is None:
        pytest.skip("MAVProxy not installed (pip install mavproxy)")
    lines: list[str] = []

    async def main() -> None:
        async with running_host(2, personality_name="ardupilot") as host:
            vehicle = host.vehicle(1)
            proc = await asyncio.create_subprocess_exec(
                sys.executable, "-m", "MAVProxy.mavproxy", f"--master=udpout:127.0.0.1:{host.ports[1]}", "--non-interactive",
                "--no-state", "--cmd=arm throttle",
                stdin=asyncio.subprocess.PIPE, stdout=asyncio.subprocess.PIPE, stderr=asyncio.subprocess.STDOUT,
                cwd=tmp_path,
            )
            try:
                async with asyncio.timeout(45):
                    while not any(f"Received {len(vehicle.params.specs)} parameters" in x for x in lines):
                        raw = await proc.stdout.readline()
                        if not raw:
                            break
                        lines.append(raw.decode(errors="replace").rstrip())
                await wait_until(lambda: vehicle.armed, 5, "armed by MAVProxy")
            finally:
                proc.terminate()
                await proc.wait()
            assert vehicle.counters.dropped == 0
            assert host.vehicle(0).counters.messages == 0

    run(main())
    text = "\n".join(lines)
    assert "Detected vehicle 2:1" in text, text
    assert "COMPONENT_ARM_DISARM: ACCEPTED" in text, text
    assert "Received 7 parameters" in text, text
