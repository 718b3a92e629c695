"""usage: sample.py OUT.json -- CMD...: run CMD, sample its agent processes' memory every 2 s (max over agents and time)."""
import json, subprocess, sys, time, psutil
out = sys.argv[1]; cmd = sys.argv[3:]
p = subprocess.Popen(cmd)
root = psutil.Process(p.pid)
best = {}; n_agents = 0
def read(pid):
    d = {}
    with open(f"/proc/{pid}/smaps_rollup") as f:
        for line in f:
            k = line.split()
            if k[0] in ("Rss:", "Pss:", "Pss_Anon:", "Pss_File:"):
                d[k[0][:-1]] = int(k[1]) / 1024
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith(("RssAnon", "RssFile")):
                k, v = line.split(":"); d[k] = int(v.split()[0]) / 1024
    return d
while p.poll() is None:
    try:
        procs = root.children(recursive=True)
    except psutil.Error:
        procs = []
    agents = []
    for c in procs:
        try:
            cl = " ".join(c.cmdline()) + " " + c.name()
            if " agent --id" in cl or "plmarl-agent" in cl:
                agents.append(c.pid)
        except psutil.Error:
            pass
    n_agents = max(n_agents, len(agents))
    for pid in agents:
        try:
            for k, v in read(pid).items():
                best[k] = max(best.get(k, 0), v)
        except OSError:
            pass
    time.sleep(2)
json.dump({"rc": p.returncode, "agents_seen": n_agents, "max": best}, open(out, "w"))
