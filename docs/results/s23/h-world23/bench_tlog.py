"""record_all of a 5 Hz bundle (one LOCAL_POSITION_NED frame) and of a 1 Hz bundle (7 frames),
and record of one received setpoint, into a real buffered file: best of 7, us per call."""
import sys, timeit, io, os
sys.argv = [sys.argv[0], "2", "1"]
import bench_host
bench_host.one_run()
v = bench_host.one_run.host.vehicles[0]
f1 = [b"\xfd" + bytes(64)]; f7 = [b"\xfd" + bytes(40 + i) for i in range(7)]; raw = b"\xfd" + bytes(70)
v.tlog = open("/tmp/hw23/t.tlog", "wb")
for name, fn in (("1 frame", lambda: v.record_all(f1)), ("7 frames", lambda: v.record_all(f7)), ("record", lambda: v.record(raw))):
    t = min(timeit.repeat(fn, number=20000, repeat=7))
    print(f"{name}: {1e6 * t / 20000:.2f} us", end="; ")
print(os.path.getsize("/tmp/hw23/t.tlog"))
