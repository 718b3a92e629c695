"""CPU (thread_time) of the world's parts over a run, split at 'mission starts'."""
import collections, logging, sys, time
if __name__ == '__main__':
    out = sys.argv[1]; argv = sys.argv[2:]
    acc = collections.defaultdict(float); cnt = collections.Counter()
    phase = ["startup"]
    depth = [0]
    def wrap(obj, name, label):
        f = getattr(obj, name)
        def w(*a, **k):
            if depth[0]:
                return f(*a, **k)
            depth[0] += 1
            t = time.thread_time()
            try:
                return f(*a, **k)
            finally:
                depth[0] -= 1
                acc[(phase[0], label)] += time.thread_time() - t; cnt[(phase[0], label)] += 1
        setattr(obj, name, w)
    from plmarl_sitl.sitl.autopilot import host, handlers, fleet
    from plmarl_sitl.sitl import world, pacer, ground
    from plmarl_sitl.sitl.autopilot import vehicle
    wrap(host._VehicleProtocol, "datagram_received", "rx datagram")
    wrap(fleet.Fleet, "step_many", "physics step_many")
    wrap(fleet.Fleet, "step", "physics step")
    wrap(host.AutopilotHost, "_after_physics", "after_physics (telemetry)")
    wrap(world.SitlWorld, "whole_second", "whole_second")
    wrap(pacer.LockstepPacer, "_place_at_start", "place")
    import asyncio.selector_events as se
    wrap(se.BaseSelectorEventLoop, "_process_events", "loop process_events")
    import selectors
    wrap(selectors.EpollSelector, "select", "epoll select")
    t0 = [time.thread_time()]
    class Split(logging.Filter):
        def filter(self, rec):
            if phase[0] == "startup" and "mission starts" in str(rec.msg):
                acc[("startup", "TOTAL")] = time.thread_time() - t0[0]; t0[0] = time.thread_time(); phase[0] = "mission"
            return True
    logging.getLogger("plmarl.world").addFilter(Split())
    sys.argv = ["plmarl"] + argv
    from plmarl_sitl.cli import main
    try:
        main()
    finally:
        acc[("mission", "TOTAL")] = time.thread_time() - t0[0]
        with open(out, "w") as fh:
            for k in sorted(acc):
                print(f"{k[0]:8s} {k[1]:28s} {acc[k]:8.3f} s {cnt[k]:8d}", file=fh)
