"""Scheduler.pop_due and the host's grouping by vehicle over 200 s of a lockstep swarm's
streams (20 vehicles, one phase, the agents' rates): best of 7, us per 5 Hz sample; and a
digest of the popped sequence."""
import hashlib, timeit, sys
from plmarl_sitl.sitl.autopilot.schedule import Scheduler
from plmarl_sitl.sitl.autopilot.telemetry import DEFAULT_RATES
from plmarl_sitl.deploy.mavlink.codec import dialect as d
import plmarl_sitl.sitl.autopilot.host as host
N = 20
def make():
    s = Scheduler(1)
    for i in range(N):
        for mid, hz in DEFAULT_RATES.items():
            s.set_rate(i, mid, hz, 0.0)
    for i in range(N):
        s.set_rate(i, d.MAVLINK_MSG_ID_LOCAL_POSITION_NED, 5.0, 3.37)
        s.set_rate(i, d.MAVLINK_MSG_ID_ATTITUDE, 0.0, 3.37)
        s.set_rate(i, d.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED, 0.0, 3.37)
        s.set_rate(i, d.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, 1.0, 3.37)
    return s
times = []
t = 3.4
for _ in range(1000):
    t += 0.2
    times.append(t)
group = getattr(host, "_due_by_vehicle", None)
def run(out=None):
    s = make()
    for now in times:
        if group is not None:
            due = group(s, now)
        else:
            due = {}
            for vi, msgid in s.pop_due(now):
                due.setdefault(vi, []).append(msgid)
        if out is not None:
            out.append(repr(list(due.items())))
out = []; run(out)
print("digest", hashlib.sha256("".join(out).encode()).hexdigest()[:16], end="  ")
tm = min(timeit.repeat(run, number=3, repeat=7)) / 3
print(f"{1e6 * tm / len(times):.1f} us per sample")
