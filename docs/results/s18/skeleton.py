"""The bare skeleton of the lockstep rig, to measure the floor of its per-sample round trip.

One world process and N agent processes (forked), one UDP socket pair per vehicle, asyncio on
both sides, as in `plmarl swarm up --lockstep`. Per step the world sends each agent one
datagram and waits for all N answers before the next step, STEPS times (2000 steps = a 200-s
mission at 10 Hz). No physics, no decision, no broker. Prints the CPU of the world and of
the agents (getrusage) and the CPU per vehicle-second.

SKEL_MAV=1: the datagrams are the rig's own: a signed LOCAL_POSITION_NED out, a signed
SET_POSITION_TARGET_LOCAL_NED back, encoded and decoded by `deploy/mavlink/codec.py`.
SKEL_TORCH=1: torch is imported before the fork, as the agents' fork server has it.

    PYTHONPATH=. SKEL_MAV=1 SKEL_TORCH=1 python docs/results/s18/skeleton.py 20 2000
"""

import asyncio
import os
import resource
import socket
import sys
import time

N = int(sys.argv[1]) if len(sys.argv) > 1 else 20
STEPS = int(sys.argv[2]) if len(sys.argv) > 2 else 2000
SIZE = 53  # a signed LOCAL_POSITION_NED: 12 header + 28 payload + 13 signature bytes
MAV = bool(os.environ.get("SKEL_MAV"))
STOP = b"x"

if os.environ.get("SKEL_TORCH"):
    import torch  # noqa: F401

if MAV:
    from pymavlink.dialects.v20 import common as d

    from plmarl_sitl.deploy.mavlink.codec import Codec, Fields

    KEY = bytes(range(32))


def agent(sock: socket.socket) -> None:
    codec = Codec(255, 191, KEY) if MAV else None

    class Answer(asyncio.DatagramProtocol):
        def __init__(self, done: asyncio.Future) -> None:
            self.done = done

        def connection_made(self, transport) -> None:  # noqa: ANN001
            self.transport = transport

        def datagram_received(self, data: bytes, addr) -> None:  # noqa: ANN001
            if data == STOP:
                self.done.set_result(None)
            elif codec is None:
                self.transport.sendto(data[:SIZE], addr)
            else:
                ms = codec.decode_datagram(data).messages[0].time_boot_ms
                setpoint = (ms, 1, 1, d.MAV_FRAME_LOCAL_NED, 0x0C3F, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.1, 0.2, 0.3, 0.0, 0.0)
                self.transport.sendto(codec.encode(Fields((d.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED, setpoint))), addr)

    async def main() -> None:
        loop = asyncio.get_running_loop()
        done = loop.create_future()
        await loop.create_datagram_endpoint(lambda: Answer(done), sock=sock)
        await done

    asyncio.run(main())


def world(socks: list[socket.socket], agents: list[tuple[str, int]]) -> None:
    codec = Codec(1, 1, KEY) if MAV else None
    owed = [0]
    all_in = asyncio.Event()

    class Collect(asyncio.DatagramProtocol):
        def datagram_received(self, data: bytes, addr) -> None:  # noqa: ANN001
            if codec is not None:
                codec.decode_datagram(data)
            owed[0] -= 1
            if owed[0] == 0:
                all_in.set()

    async def main() -> None:
        loop = asyncio.get_running_loop()
        links = [(await loop.create_datagram_endpoint(Collect, sock=s))[0] for s in socks]
        payload = bytes(SIZE)
        for step in range(STEPS):
            all_in.clear()
            owed[0] = N
            for link, addr in zip(links, agents, strict=True):
                if codec is not None:
                    sample = (step * 100, 1.0, 2.0, -60.0, 0.1, 0.2, 0.0)
                    payload = codec.encode(Fields((d.MAVLINK_MSG_ID_LOCAL_POSITION_NED, sample)))
                link.sendto(payload, addr)
            await all_in.wait()
        for link, addr in zip(links, agents, strict=True):
            link.sendto(STOP, addr)

    asyncio.run(main())


def udp() -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    return s


def cpu(r: resource.struct_rusage) -> float:
    return r.ru_utime + r.ru_stime


if __name__ == "__main__":
    world_socks = [udp() for _ in range(N)]
    agent_socks = [udp() for _ in range(N)]
    pids = []
    for i in range(N):
        pid = os.fork()
        if pid == 0:
            agent(agent_socks[i])
            os._exit(0)
        pids.append(pid)
    addrs = [s.getsockname() for s in agent_socks]
    for s in agent_socks:
        s.close()
    t0, c0 = time.perf_counter(), resource.getrusage(resource.RUSAGE_SELF)
    world(world_socks, addrs)
    c1, wall = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter() - t0
    for pid in pids:
        os.waitpid(pid, 0)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    world_cpu, agents_cpu = cpu(c1) - cpu(c0), cpu(children)
    vehicle_s = N * STEPS / 10
    print(f"N={N} steps={STEPS} mav={MAV} torch={'torch' in sys.modules} wall {wall:.2f} s world {world_cpu:.2f} s "
          f"agents {agents_cpu:.2f} s (user {children.ru_utime:.2f}, sys {children.ru_stime:.2f}); "
          f"per vehicle-second {1000 * (world_cpu + agents_cpu) / vehicle_s:.2f} ms")
