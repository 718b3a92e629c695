"""usage: harness.py POLICY MISSION INPUTS.npz: the agents' forkserver in process (sitl/forked_child
with POLICY and MISSION preloaded), then a forked child that makes its plan's first map on the
t = 0 instant of INPUTS (docs/results/session13/mkin.py MISSION INPUTS) and 200 predictor +
policy calls with N - 1 neighbours; RssAnon/RssFile of the server and of the child at each step,
and the child's file pages by library. WARM=K in the environment: K more dry runs in the server."""
import collections
import json
import os
import sys

policy, mission, inputs = sys.argv[1:4]
os.environ["PLMARL_AGENT_PRELOAD"] = json.dumps({"policy": policy, "mission": mission})
import plmarl_sitl.sitl.forked_child  # noqa: E402, F401  (what the forkserver runs)


def status(tag: str) -> None:
    d = {}
    for line in open("/proc/self/status"):
        if line.startswith(("VmRSS", "RssAnon", "RssFile")):
            k, v = line.split(":")
            d[k] = round(int(v.split()[0]) / 1024, 1)
    print(tag, d, flush=True)


def file_pages(tag: str) -> None:
    agg = collections.Counter()
    name = None
    for line in open("/proc/self/smaps"):
        p = line.split()
        if not p[0].endswith(":"):
            name = os.path.basename(p[-1]) if len(p) > 5 else "[anon]"
            continue
        if p[0] == "Rss:":
            agg[name] += int(p[1])
        if p[0] == "Anonymous:":
            agg[name] -= int(p[1])
    print(tag, [(k, round(v / 1024, 1)) for k, v in agg.most_common(8)], flush=True)


import numpy as np  # noqa: E402
import torch  # noqa: E402

from plmarl_sitl.deploy.agent import preload  # noqa: E402
from plmarl_sitl.deploy.agent.coordination import agent_plan  # noqa: E402
from plmarl_sitl.learning.nn.contract import PolicyInputs  # noqa: E402
from plmarl_sitl.learning.nn.features import STATE_DIM  # noqa: E402
from plmarl_sitl.model.coverage import SENSING_FEATURES  # noqa: E402
from plmarl_sitl.model.demand import DEMAND_CELL_FIELDS  # noqa: E402

lp = preload.preloaded(policy, mission)
m = preload.preloaded_mission(mission)
if int(os.environ.get("WARM", "0")):
    from plmarl_sitl.learning.nn.io import dry_run

    for _ in range(int(os.environ["WARM"])):
        dry_run(lp.tracker, lp.call)
    preload.release_free_heap()
status("server")
if os.fork() == 0:
    status("child at fork")
    d = np.load(inputs)
    t_rx = torch.from_numpy(d["t_rx"])
    mask = t_rx >= 0
    mask[0] = False
    agent_plan(m, 0).target(0, torch.from_numpy(d["ego"]), torch.from_numpy(d["held"]), t_rx, (0.0, torch.from_numpy(d["cells"])), mask)
    status("child after the first map")
    n = m.n_uavs - 1
    with torch.no_grad():
        held = torch.zeros(n, STATE_DIM)
        buf, seen = lp.tracker.init_state(held)
        for i in range(200):
            belief, _, _, _ = lp.tracker(float(i), held, torch.zeros(n), buf, seen)
            lp.call(PolicyInputs(torch.zeros(STATE_DIM), belief, torch.ones(n, dtype=torch.bool), torch.zeros(SENSING_FEATURES),
                                 torch.tensor(False), torch.zeros(30, DEMAND_CELL_FIELDS), torch.zeros(2)))
    status("child after 200 decisions")
    file_pages("child's file pages")
    os._exit(0)
os.wait()
