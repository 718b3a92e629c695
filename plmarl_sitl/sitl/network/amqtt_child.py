"""`python -m plmarl_sitl.sitl.network.amqtt_child --port P`: the embedded amqtt broker in a process of
its own (`broker.AmqttProcess`).

amqtt is pure Python and needs many event-loop turns per message. Inside the launcher it
shares a loop with the SITL world, which steps 20 vehicles between turns, and at 20x the
broker falls ever further behind (sensing arrived 170 mission seconds late). In its own
process it gets its own turns and the OS schedules it like any broker. Like every broker
child it dies with the process that started it (`proc.die_with_parent`, set at spawn).
"""

from __future__ import annotations

import argparse
import asyncio
import json
import signal

from plmarl_sitl.sitl.network.broker import EmbeddedBroker


async def _serve(host: str, port: int, plugins: dict | None) -> None:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGINT, signal.SIGTERM):
        loop.add_signal_handler(sig, stop.set)
    async with EmbeddedBroker(host, port, plugins):
        await stop.wait()


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--host", default="127.0.0.1")
    p.add_argument("--port", type=int, required=True)
    p.add_argument("--plugins", default=None, help="JSON file: amqtt's plugins configuration (default: anonymous)")
    args = p.parse_args()
    plugins = json.loads(open(args.plugins).read()) if args.plugins else None  # noqa: SIM115, PTH123
    asyncio.run(_serve(args.host, args.port, plugins))


if __name__ == "__main__":
    main()
