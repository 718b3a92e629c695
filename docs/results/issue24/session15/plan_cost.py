# ruff: noqa  (session-15 harness kept to reproduce docs/RESULTS.md; not product code)
"""Cost of the deployed agent's new map (AgentPlan.target at a decision with a new map: the
re-placement and re-assignment), per placement, interleaved call by call in one process so the
machine's load falls on all alike; `plmarl bench infer`'s lattice mission and inputs.

    PYTHONPATH=. python docs/results/issue24/session15/plan_cost.py N AREA_M CALLS greedy,search,learned
"""
import sys, time
import numpy as np
import torch
torch.set_num_threads(1)
from plmarl_sitl.bench.infer import plan_inputs
from plmarl_sitl.deploy.agent.plan import AgentPlan

n, area, calls, kinds = int(sys.argv[1]), float(sys.argv[2]), int(sys.argv[3]), sys.argv[4].split(",")
pi = plan_inputs(n, 0, area)
full = torch.ones(n, dtype=torch.bool); full[0] = False
tau = int(pi.mission.timing.decision_every_s)
plans = {}
for k in kinds:
    p = AgentPlan(pi.mission.with_placement(k), 0)
    p.target(0, pi.ego, pi.held, pi.t_rx, (0.0, pi.maps[0]), full)
    plans[k] = [p, 0, 0]
wall = {k: [] for k in kinds}; cpu = {k: [] for k in kinds}
for i in range(calls):
    for k in kinds:
        p, t, m = plans[k]
        t += tau; m += 1
        plans[k][1:] = [t, m]
        w0, c0 = time.perf_counter_ns(), time.thread_time_ns()
        p.target(t, pi.ego, pi.held, pi.t_rx, (float(m), pi.maps[m % 2]), full)
        wall[k].append((time.perf_counter_ns() - w0) / 1e6); cpu[k].append((time.thread_time_ns() - c0) / 1e6)
for k in kinds:
    print(f"N {n} area {area:g} m  {k:8s} new map: wall median {np.median(wall[k]):.1f} ms p90 {np.percentile(wall[k], 90):.1f}; "
          f"CPU median {np.median(cpu[k]):.1f} ms p90 {np.percentile(cpu[k], 90):.1f} ({calls} calls)")
