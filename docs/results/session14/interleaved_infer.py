"""The bench infer rows for pl-marl + team plan, N = 4 and N = 100 (3 km) interleaved call by call
in one process (so load hits both N alike); CPU medians (thread_time). usage: inter.py CALLS OUT.json"""
import json, sys, time, os
import numpy as np, torch
torch.set_num_threads(1)
from plmarl_sitl.bench.infer import _modules, plan_inputs
from plmarl_sitl.config import PROJECT_POLICIES
from plmarl_sitl.deploy.agent.coordination import agent_plan
from plmarl_sitl.learning.nn.contract import PolicyCall, PolicyInputs
from plmarl_sitl.model.coverage import SENSING_FEATURES
calls = int(sys.argv[1])
tracker, policy, _ = _modules("pl-marl", PROJECT_POLICIES / "pl-marl")
call = PolicyCall(policy)
gen = torch.Generator().manual_seed(0)
st = {}
for n in (4, 100):
    pi = plan_inputs(n, 0, 3000.0)
    m = n - 1
    held = torch.cat([torch.rand(m, 3, generator=gen) * torch.tensor([3000.0, 3000.0, -100.0]), torch.randn(m, 3, generator=gen)], -1)
    t_rx = torch.zeros(m)
    with torch.inference_mode():
        buf, seen = tracker.init_state(held)
        _, _, buf, seen = tracker(0.0, held, t_rx, buf, seen)
    full = torch.ones(n, dtype=torch.bool); full[0] = False
    plan = agent_plan(pi.mission.with_coordination("team"), 0)
    target = plan.target(0, pi.ego, pi.held, pi.t_rx, (0.0, pi.maps[0]), full)
    st[n] = dict(pi=pi, held=held, t_rx=t_rx, buf=buf, seen=seen, full=full, plan=plan, target=target, kt=[0, 0],
                 ego=torch.tensor([1500.0, 1500.0, -100.0, 1.0, 0.0, 0.0]), mask=torch.ones(m, dtype=torch.bool),
                 sense=torch.rand(SENSING_FEATURES, generator=gen), demand=pi.maps[0])
def decide(s):
    belief, _, _, _ = tracker(7.0, s["held"], s["t_rx"], s["buf"], s["seen"])
    call(PolicyInputs(s["ego"], belief, s["mask"], s["sense"], torch.tensor(False), s["demand"], s["target"]))
def plan_step(s, new_map):
    if new_map: s["kt"][1] += 1
    s["kt"][0] += 3
    s["plan"].target(s["kt"][0], s["pi"].ego, s["pi"].held, s["pi"].t_rx, (float(s["kt"][1]), s["pi"].maps[s["kt"][1] % 2]), s["full"])
cpu = {(n, r): [] for n in (4, 100) for r in ("policy", "decision", "new map")}
with torch.inference_mode():
    for i in range(300 + calls):
        for n in (4, 100):
            s = st[n]
            c0 = time.thread_time_ns(); decide(s); c1 = time.thread_time_ns()
            nm = i % 10 == 0
            plan_step(s, nm); c2 = time.thread_time_ns()
            if i >= 300:
                cpu[(n, "policy")].append(c1 - c0); cpu[(n, "new map" if nm else "decision")].append(c2 - c1)
res = {f"{r} N={n}": float(np.median(v)) / 1e3 for (n, r), v in cpu.items()}
for n in (4, 100):
    res[f"pl-marl + team plan N={n}"] = res[f"policy N={n}"] + (9 * res[f"decision N={n}"] + res[f"new map N={n}"]) / 10
res["ratio"] = res["pl-marl + team plan N=100"] / res["pl-marl + team plan N=4"]
res["load"] = os.getloadavg()[0]
json.dump(res, open(sys.argv[2], "w"))
print(json.dumps({k: round(v, 2) for k, v in res.items()}))
