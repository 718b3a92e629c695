"""Subscriber CPU per MQTT message through `MqttBus` (the agent's bus), on a real mosquitto.

`PYTHONPATH=TREE python3 docs/results/s18_agent/bench_bus.py [BURSTS]`: a publisher process (paho,
blocking) sends BURSTS bursts of 20 messages of 300 bytes (an instant's relayed states), one burst
every 2 ms; this process subscribes with `MqttBus` and counts its process CPU from the first
message to the last."""

from __future__ import annotations

import asyncio
import os
import subprocess
import sys
import time

from plmarl_sitl.deploy.mqtt.transport import MqttBus
from plmarl_sitl.sitl.network.broker import MosquittoBroker

PER = 20
PUBLISHER = r"""
import sys, time
import paho.mqtt.client as mqtt
c = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, "pub")
c.connect(sys.argv[1], int(sys.argv[2]))
c.loop_start()
time.sleep(0.5)
for b in range(int(sys.argv[3])):
    for i in range(20):
        c.publish(f"b/{i}", bytes(300))
    time.sleep(0.002)
time.sleep(0.5)
c.loop_stop()
"""


async def main(broker: MosquittoBroker, bursts: int) -> None:
    want = bursts * PER
    got = 0
    cpu: dict[str, float] = {}

    def on_message(_topic: str, _payload: bytes) -> None:
        nonlocal got
        if got == 0:
            cpu["first"] = time.process_time()
        got += 1
        if got == want:
            cpu["last"] = time.process_time()

    bus = MqttBus(broker.url, "sub", ["b/#"], on_message, name="sub")
    task = asyncio.create_task(bus.run())
    await bus.connected.wait()
    pub = subprocess.Popen([sys.executable, "-c", PUBLISHER, broker.host, str(broker.port), str(bursts)])
    while got < want and pub.poll() is None:
        await asyncio.sleep(0.05)
    await asyncio.sleep(0.5)
    pub.wait()
    task.cancel()
    await asyncio.gather(task, return_exceptions=True)
    if got < want:
        print(f"{os.environ.get('PYTHONPATH')}: only {got}/{want} messages arrived")
        return
    print(f"{os.environ.get('PYTHONPATH')}: {got} messages, {(cpu['last'] - cpu['first']) / got * 1e6:.2f} us CPU per message")


if __name__ == "__main__":
    with MosquittoBroker() as b:
        asyncio.run(main(b, int(sys.argv[1]) if len(sys.argv) > 1 else 500))
