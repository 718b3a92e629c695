# run the CLI in-process with thread_time accumulators around the world's hot functions;
# print totals and the split at the mission start (LockstepPacer._place_at_start)
import atexit, os, sys, runpy, time, functools, collections
tt = time.thread_time
acc = collections.Counter(); calls = collections.Counter(); snap = {}
depth = [0]
def wrap(cls, name, label=None):
    f = getattr(cls, name); label = label or f"{cls.__name__}.{name}"
    @functools.wraps(f)
    def w(*a, **k):
        t = tt()
        try:
            return f(*a, **k)
        finally:
            acc[label] += tt() - t; calls[label] += 1
    setattr(cls, name, w)
from plmarl_sitl.sitl.autopilot import host, vehicle, schedule, fleet, handlers
from plmarl_sitl.sitl import world, pacer, ground
from plmarl_sitl.sitl.network import relay
wrap(host.AutopilotHost, "advance_substeps"); wrap(host.AutopilotHost, "_substep"); wrap(host.AutopilotHost, "_after_physics")
wrap(fleet.Fleet, "step_many"); wrap(fleet.Fleet, "step")
wrap(host._VehicleProtocol, "datagram_received")
wrap(vehicle.Vehicle, "send_bundle"); wrap(vehicle.Vehicle, "record_all"); wrap(vehicle.Vehicle, "update")
wrap(schedule.Scheduler, "pop_due")
wrap(world.SitlWorld, "whole_second")
wrap(ground.Ground, "sense"); wrap(ground.Ground, "measure"); wrap(ground.Ground, "step_to")
wrap(relay.Relay, "pump")
orig_place = pacer.LockstepPacer._place_at_start
def place(self):
    snap.update(acc); snap["_cpu"] = os.times().user + os.times().system
    return orig_place(self)
pacer.LockstepPacer._place_at_start = place
t0 = os.times()
def report():
    t = os.times(); tot = t.user + t.system - t0.user - t0.system
    print(f"WORLDCPU total={tot:.2f} at_start={snap.get('_cpu', 0) - t0.user - t0.system:.2f}", file=sys.stderr)
    for k, v in sorted(acc.items(), key=lambda kv: -kv[1]):
        print(f"ACC {k:40s} total={v:6.2f} mission={v - snap.get(k, 0):6.2f} calls={calls[k]}", file=sys.stderr)
atexit.register(report)
sys.argv = ["plmarl"] + sys.argv[1:]
runpy.run_module("plmarl_sitl.cli", run_name="__main__")
