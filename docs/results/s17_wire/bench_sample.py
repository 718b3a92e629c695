"""Per-sample MAVLink path of a lockstep SITL swarm, in one process, old tree vs new.

`PYTHONPATH=TREE python3 docs/results/s17_wire/bench_sample.py [--cold] [--n N]`

One emulated autopilot (signed, as `plmarl swarm up` runs them) and one agent link opened
to it over real UDP sockets; then, per sample, timed piece by piece:
  world_tx:  the world builds and sends LOCAL_POSITION_NED (`BUILDERS` + `send_bundle`),
  agent_rx:  the agent's link parses that datagram and hands it to a registered handler
             (`feed_datagram` -> `Subscription.handle_with`), which reads its fields,
  agent_tx:  the agent's setpoint (`send_accel_ned`: pack, sign, sendto),
  world_rx:  the world's handler of that setpoint datagram (`handlers.on_datagram`).
--cold: between two samples, write 8 MiB (evicting the caches, as 20 agents and a world
taking turns on 2 cores do); only the sample's pieces are timed, in thread CPU time
(time.thread_time_ns: a loaded machine preempting the benchmark does not count). Prints
medians and 10th percentiles in us. --calls: instead, the Python and C function calls of each piece (the
same on any machine).
"""

from __future__ import annotations

import argparse
import asyncio
import os
import socket
import statistics
import sys
import time

import numpy as np

from plmarl_sitl.deploy.mavlink.client import VehicleLink
from plmarl_sitl.sitl.autopilot import handlers, telemetry
from plmarl_sitl.sitl.autopilot.host import AutopilotHost

KEY = bytes(range(32))
LPN = telemetry.message_id("LOCAL_POSITION_NED")


async def main(n: int, cold: bool, calls: bool = False) -> None:
    host = AutopilotHost(1, personality_name="px4", signing_key=KEY, base_port=17540)
    await host.start()
    link = VehicleLink("127.0.0.1", 17540, signing_key=KEY)

    async def run_clock() -> None:  # the world's clock until the link is open (heartbeats)
        while True:
            host.advance(0.02)
            await asyncio.sleep(0.01)

    clock = asyncio.create_task(run_clock())
    await link.open(timeout=5.0)
    clock.cancel()
    v = host.vehicle(0)
    got = []
    sub = link.subscribe("LOCAL_POSITION_NED")
    sub.handle_with(lambda m: got.append((m.time_boot_ms, m.x, m.y, m.z, m.vx, m.vy, m.vz)))
    # What the world sends, captured: the agent's socket gets it (read it back directly).
    sock = socket.socket(fileno=os.dup(link._transport.get_extra_info("socket").fileno()))  # noqa: SLF001 - benchmark only
    vsock = socket.socket(fileno=os.dup(v.transport.get_extra_info("socket").fileno()))
    sock.setblocking(False)
    vsock.setblocking(False)
    flush = np.zeros(1 << 20)  # 8 MiB
    times = {k: [] for k in ("world_tx", "agent_rx", "agent_tx", "world_rx")}
    await asyncio.sleep(0.2)
    for _ in range(50):  # drain what the open left
        try:
            sock.recv(4096)
        except BlockingIOError:
            break
    for _ in range(50):
        try:
            vsock.recvfrom(4096)
        except BlockingIOError:
            break
    if calls:
        _count_calls(host, v, link, sock, vsock, got)
        link.close()
        host.close()
        return
    pn = time.thread_time_ns  # CPU time of this thread: not the time other processes had the core
    for i in range(n):
        host.now = 10.0 + i * 0.1
        if cold:
            flush += 1.0
        t0 = pn()
        v.send_bundle([telemetry.BUILDERS[LPN](v)])
        t1 = pn()
        data = sock.recv(4096)
        t2 = pn()
        link.feed_datagram(data)
        t3 = pn()
        link.send_accel_ned(0.1 * (i % 7), -0.2, 0.05 * (i % 3), time_boot_ms=got[-1][0])
        t4 = pn()
        sp, addr = vsock.recvfrom(4096)
        t5 = pn()
        handlers.on_datagram(v, sp, addr)
        t6 = pn()
        times["world_tx"].append(t1 - t0)
        times["agent_rx"].append(t3 - t2)
        times["agent_tx"].append(t4 - t3)
        times["world_rx"].append(t6 - t5)
    assert len(got) == n, len(got)
    assert v.counters.dropped == 0, v.counters.summary()
    for name, stat in (("median", statistics.median), ("p10", lambda x: sorted(x)[len(x) // 10])):
        print(" ".join(f"{k} {stat(x) / 1000:.2f}" for k, x in times.items()),
              f"sum {sum(stat(x) for x in times.values()) / 1000:.2f} us ({name}, n={n}, cold={cold})")
    link.close()
    host.close()


def _count_calls(host, v, link, sock, vsock, got) -> None:  # noqa: ANN001
    """Python and C function calls per piece of one sample (sys.setprofile), averaged
    over 100 samples: what a sample touches, independent of the machine's load."""
    counts = {k: 0 for k in ("world_tx", "agent_rx", "agent_tx", "world_rx")}
    current = [""]

    def prof(frame, event, arg) -> None:  # noqa: ANN001
        if event in ("call", "c_call") and current[0]:
            counts[current[0]] += 1

    def piece(name, fn):  # noqa: ANN001, ANN202
        current[0] = name
        sys.setprofile(prof)
        try:
            return fn()
        finally:
            sys.setprofile(None)
            current[0] = ""

    n = 100
    for i in range(n):
        host.now = 10.0 + i * 0.1
        piece("world_tx", lambda: v.send_bundle([telemetry.BUILDERS[LPN](v)]))
        data = sock.recv(4096)
        piece("agent_rx", lambda data=data: link.feed_datagram(data))
        piece("agent_tx", lambda: link.send_accel_ned(0.1, -0.2, 0.05, time_boot_ms=got[-1][0]))
        sp, addr = vsock.recvfrom(4096)
        piece("world_rx", lambda sp=sp, addr=addr: handlers.on_datagram(v, sp, addr))
    print(" ".join(f"{k} {c / n:.1f}" for k, c in counts.items()), f"sum {sum(counts.values()) / n:.1f} calls per sample")


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=5000)
    ap.add_argument("--cold", action="store_true")
    ap.add_argument("--calls", action="store_true", help="count the function calls per piece instead of timing")
    a = ap.parse_args()
    asyncio.run(main(a.n, a.cold, a.calls))
