"""Time Fleet._free_steps(h, 10) (the 10 quiet substeps between two 5 Hz samples) on the
fleet of bench_host after SECONDS of flight: best of 7 x 2000 calls, us per call."""
import sys, timeit
sys.argv = [sys.argv[0], "20", "1"]
import bench_host
bench_host.one_run()
f = bench_host.one_run.host.fleet
print("free", f._free_steps(f.physics_dt if hasattr(f, "physics_dt") else 0.02, 10) is not None)
t = min(timeit.repeat(lambda: f._free_steps(0.02, 10), number=2000, repeat=7))
print(f"_free_steps(0.02, 10): {1e6 * t / 2000:.1f} us")
