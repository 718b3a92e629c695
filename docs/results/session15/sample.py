"""usage: sample.py OUT.json -- CMD...: run CMD; every 2 s the VmRSS/RssAnon/RssFile (status) and
Rss/Pss (smaps_rollup) of every agent process in its tree (forked `plmarl-agentI`, or exec'd
`... agent --id I`), max over agents and time and per agent; every 10 s the smaps of the largest
agent grouped by mapping (kept for the largest seen), and the forkserver's. Session 15, issue 24.2."""
import collections
import json
import os
import subprocess
import sys
import time

import psutil

ROLLUP = ("Rss:", "Pss:", "Pss_Anon:", "Pss_File:", "Private_Dirty:")
STATUS = ("VmRSS", "RssAnon", "RssFile")
SMAPS = ("Rss:", "Pss:", "Private_Dirty:", "Anonymous:", "Shared_Clean:", "Private_Clean:", "Shared_Dirty:")


def status(pid: int) -> dict[str, float]:
    d = {}
    with open(f"/proc/{pid}/smaps_rollup") as f:
        for line in f:
            k = line.split()
            if k[0] in ROLLUP:
                d[k[0][:-1]] = int(k[1]) / 1024
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith(STATUS):
                k, v = line.split(":")
                d[k] = int(v.split()[0]) / 1024
    return d


def smaps(pid: int) -> dict[str, dict[str, float]]:
    agg: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
    name = None
    with open(f"/proc/{pid}/smaps") as f:
        for line in f:
            parts = line.split()
            if not parts[0].endswith(":"):
                name = parts[5] if len(parts) > 5 else "[anon]"
                name = os.path.basename(name) if name.startswith("/") else name
            elif parts[0] in SMAPS:
                agg[name][parts[0][:-1]] += int(parts[1])
    return {k: {kk: vv / 1024 for kk, vv in v.items()} for k, v in agg.items()}


def agents_and_server(root: psutil.Process) -> tuple[dict[int, str], int | None]:
    agents, server = {}, None
    try:
        procs = root.children(recursive=True)
    except psutil.Error:
        return agents, server
    for c in procs:
        try:
            name, cmd = c.name(), " ".join(c.cmdline())
        except psutil.Error:
            continue
        if name.startswith("plmarl-agent"):
            agents[c.pid] = name
        elif " agent --id " in cmd:
            agents[c.pid] = "exec:" + cmd.split(" agent --id ")[1].split()[0]
        elif "forkserver" in cmd:
            server = c.pid
    return agents, server


def main() -> None:
    out, cmd = sys.argv[1], sys.argv[3:]
    p = subprocess.Popen(cmd)
    root = psutil.Process(p.pid)
    best: dict[str, float] = {}
    per: dict[str, dict[str, float]] = {}
    n_agents, big, server, t_last, t0 = 0, None, None, 0.0, time.time()
    while p.poll() is None:
        agents, fs = agents_and_server(root)
        n_agents = max(n_agents, len(agents))
        top = None
        for pid, label in agents.items():
            try:
                s = status(pid)
            except OSError:
                continue
            if "VmRSS" not in s:  # exiting (a zombie has no memory)
                continue
            for k, v in s.items():
                best[k] = max(best.get(k, 0.0), v)
            mine = per.setdefault(label, {})
            for k in ("VmRSS", "Pss"):
                mine[k] = max(mine.get(k, 0.0), s.get(k, 0.0))
            if top is None or s["VmRSS"] > top[1]:
                top = (pid, s["VmRSS"])
        if top and time.time() - t_last > 10:
            t_last = time.time()
            try:
                if big is None or top[1] >= big["VmRSS"]:
                    big = {"pid": top[0], "t": round(time.time() - t0), "VmRSS": top[1], "status": status(top[0]), "smaps": smaps(top[0])}
                if fs:
                    server = {"pid": fs, "status": status(fs), "smaps": smaps(fs)}
            except OSError:
                pass
        time.sleep(2)
    rss = sorted(v["VmRSS"] for v in per.values())
    json.dump({"rc": p.returncode, "agents_seen": n_agents, "max": best, "agent_rss_max_median": rss[len(rss) // 2] if rss else None,
               "per_agent": per, "largest": big, "server": server}, open(out, "w"))


if __name__ == "__main__":
    main()
