"""Replay a lockstep mission's sample loop on an AutopilotHost: 20 PX4 vehicles flying signed
acceleration setpoints answered to each LOCAL_POSITION_NED (5 Hz), the agents' streams
(ATTITUDE and POSITION_TARGET off, GLOBAL_POSITION_INT 1 Hz), .tlogs recorded in memory.
Prints CPU per mission second (best of REPEATS) and a sha256 of every byte sent and recorded.
usage: PYTHONPATH=TREE python bench_host.py [seconds] [repeats]"""
import hashlib, io, random, sys, time, math
FIXED_UNIX = 1_800_000_000.0
time.time = lambda: FIXED_UNIX  # signing timestamps and tlog stamps: the same bytes every run
from plmarl_sitl.sitl.autopilot.host import AutopilotHost, _VehicleProtocol
from plmarl_sitl.sitl.autopilot import telemetry
from plmarl_sitl.deploy.mavlink.codec import Codec, dialect as d
from plmarl_sitl.deploy.mavlink.wire import ACCEL_ONLY

N = 20
SECONDS = int(sys.argv[1]) if len(sys.argv) > 1 else 60
REPEATS = int(sys.argv[2]) if len(sys.argv) > 2 else 3

class Transport:
    def __init__(self, out): self.out = out
    def sendto(self, buf, addr): self.out.append(buf)
    def is_closing(self): return False

def one_run():
    keys = [bytes([i + 1]) * 32 for i in range(N)]
    host = AutopilotHost(N, personality_name="px4", signing_keys=keys, stream_phases=1,
                         home_offsets_ned=[(25.0 * i, 0.0, 0.0) for i in range(N)])
    sent = [[] for _ in range(N)]
    protos = []
    agents = []
    for i, v in enumerate(host.vehicles):
        v.transport = Transport(sent[i]); v.tlog = io.BytesIO()
        v.remember_peer(("127.0.0.1", 20000 + i))
        protos.append(_VehicleProtocol(v))
        agents.append(Codec(200 + i, 191, keys[i]))
    f = host.fleet
    for i in range(N):
        f.streams.set_rate(i, d.MAVLINK_MSG_ID_LOCAL_POSITION_NED, 5.0, f.now)
        f.streams.set_rate(i, d.MAVLINK_MSG_ID_ATTITUDE, 0.0, f.now)
        f.streams.set_rate(i, d.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED, 0.0, f.now)
        f.streams.set_rate(i, d.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, 1.0, f.now)
    rng = random.Random(0)
    def setpoint(i, ms):
        a = agents[i]
        msg = a.mav.set_position_target_local_ned_encode(ms, host.vehicles[i].sysid, 1, d.MAV_FRAME_LOCAL_NED, ACCEL_ONLY,
                                                         0, 0, 0, 0, 0, 0, rng.uniform(-3, 3), rng.uniform(-3, 3), rng.uniform(-0.5, 0.5), 0, 0)
        return a.encode(msg)
    for i, v in enumerate(host.vehicles):  # flying offboard at 60 m
        host.place(i, (0.0, 0.0, -60.0))
        protos[i].datagram_received(setpoint(i, 0), ("127.0.0.1", 20000 + i))
        v.armed = True
        v.mode_spec = v.personality.mode(v.personality.offboard_mode)
        protos[i].datagram_received(setpoint(i, 0), ("127.0.0.1", 20000 + i))
    next_second = math.floor(f.now) + 1.0
    end = f.now + SECONDS
    t_cpu = 0.0
    while f.now < end - 1e-9:
        # the agents' answers to the latest LOCAL_POSITION_NED (built outside the timed part)
        grams = [(i, setpoint(i, int(f.telemetry_ms[i]))) for i in range(N) if f.answered_ms[i] < f.telemetry_ms[i]]
        t = time.process_time()
        for i, g in grams:
            protos[i].datagram_received(g, ("127.0.0.1", 20000 + i))
        host.advance_substeps(50, next_second)
        t_cpu += time.process_time() - t
        if f.now >= next_second - 1e-9:
            next_second += 1.0
    h = hashlib.sha256()
    for i, v in enumerate(host.vehicles):
        for b in sent[i]: h.update(b)
        h.update(v.tlog.getvalue())
    h.update(f.pos_np.tobytes()); h.update(f.vel_np.tobytes())
    one_run.host = host
    return t_cpu, h.hexdigest()[:16], sum(map(len, sent))

if __name__ == '__main__':
  res = [one_run() for _ in range(REPEATS)]
  cpu = sorted(r[0] for r in res)
  print(f"us per vehicle-second: best {1e6 * cpu[0] / (N * SECONDS):.1f} median {1e6 * cpu[len(cpu)//2] / (N * SECONDS):.1f}"
      f"  datagrams {res[0][2]}  sha {res[0][1]} {'same' if len({r[1] for r in res}) == 1 else 'DIFFER'}")
