# run the CLI in-process and time the garbage collector's passes (per generation) in the world
import gc, os, sys, runpy, time, collections
acc = collections.Counter(); n = collections.Counter(); t0 = [0.0]
def cb(phase, info):
    if phase == "start":
        t0[0] = time.thread_time()
    else:
        acc[info["generation"]] += time.thread_time() - t0[0]; n[info["generation"]] += 1
        if info["generation"] == 2: print(f"GC2 at {time.time():.2f} took {time.thread_time() - t0[0]:.3f} collected {info['collected']}", file=sys.stderr, flush=True)
gc.callbacks.append(cb)
def report():
    t = os.times()
    print(f"WORLDCPU user={t.user:.2f} sys={t.system:.2f}", file=sys.stderr)
    for g in sorted(acc): print(f"GC gen{g}: {n[g]} passes, {acc[g]:.3f} s", file=sys.stderr)
    print("objects tracked", len(gc.get_objects()), file=sys.stderr)
import atexit; atexit.register(report)
sys.argv = ["plmarl"] + sys.argv[1:]
runpy.run_module("plmarl_sitl.cli", run_name="__main__")
