"""Forkserver-like: imports + preload, then fork an 'agent' that imports the agent program and runs its plan's first map; RSS of both.
usage: rss2.py POLICY MISSION INPUTS.npz"""
import os, sys, json
def roll():
    out = {}
    for line in open("/proc/self/smaps_rollup"):
        p = line.split()
        if p[0] in ("Rss:", "Pss:"):
            out[p[0][:-1]] = int(p[1]) // 1024
    for line in open("/proc/self/status"):
        if line.startswith(("RssAnon", "RssFile")):
            k, v = line.split(":"); out[k] = int(v.split()[0]) // 1024
    return out
import plmarl_sitl.sitl.forked_child  # noqa
import plmarl_sitl.deploy.agent.preload as pre
import gc
pre.preload(sys.argv[1], sys.argv[2]); gc.freeze()
res = {"server": roll()}
r, w = os.pipe()
pid = os.fork()
if pid == 0:
    import numpy as np, torch
    import plmarl_sitl.deploy.agent.program  # noqa: the agent's modules
    from plmarl_sitl.mission import load_mission
    from plmarl_sitl.deploy.agent.coordination import agent_plan
    m = load_mission(sys.argv[2]); d = np.load(sys.argv[3])
    p = agent_plan(m, 0)
    t_rx = torch.from_numpy(d["t_rx"]); mask = t_rx >= 0; mask[0] = False
    p.target(0, torch.from_numpy(d["ego"]), torch.from_numpy(d["held"]), t_rx, (0.0, torch.from_numpy(d["cells"])), mask)
    os.write(w, json.dumps(roll()).encode()); os._exit(0)
os.close(w); data = os.read(r, 100000); os.waitpid(pid, 0)
res["agent_after_first_map"] = json.loads(data)
print(json.dumps(res))
