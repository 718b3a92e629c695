"""usage: sample.py OUT.json -- CMD...: run CMD (a `plmarl swarm up`); every 2 s the RSS, PSS and USS
(/proc/PID/smaps_rollup: Rss, Pss, Private_Clean + Private_Dirty) of every forked agent
(`plmarl-agentI`) in its tree, each agent's peak of each over the run; the agents' median and
max of those peaks; the fork server's (the session-16 `forkserver` or the session-17
`plmarl-forksrv`) anonymous RSS; and the wall time from start to the last agent forked and to
the first `mission starts` in RUN/launcher.log (RUN: the CMD's --out). Session 17, issue 24.2."""
import json
import statistics
import subprocess
import sys
import time

import psutil


def rollup(pid: int) -> dict[str, float]:
    d: dict[str, float] = {}
    with open(f"/proc/{pid}/smaps_rollup") as f:
        for line in f:
            k = line.split()
            if k[0] in ("Rss:", "Pss:", "Private_Clean:", "Private_Dirty:", "Anonymous:"):
                d[k[0][:-1]] = int(k[1]) / 1024
    d["Uss"] = d.pop("Private_Clean", 0.0) + d.pop("Private_Dirty", 0.0)
    return d


def main() -> None:
    out, cmd = sys.argv[1], sys.argv[3:]
    run = cmd[cmd.index("--out") + 1]
    t0 = time.time()
    p = subprocess.Popen(cmd)
    root = psutil.Process(p.pid)
    peaks: dict[str, dict[str, float]] = {}
    server: dict[str, float] = {}
    n_max, t_all, t_start = 0, None, None
    while p.poll() is None:
        try:
            procs = root.children(recursive=True)
        except psutil.Error:
            break
        n = 0
        for c in procs:
            try:
                name, cmdline = c.name(), " ".join(c.cmdline())
                if name.startswith("plmarl-agent"):
                    n += 1
                    r = rollup(c.pid)
                    if r.get("Rss", 0.0) == 0.0:
                        continue
                    mine = peaks.setdefault(name, {})
                    for k, v in r.items():
                        mine[k] = max(mine.get(k, 0.0), v)
                elif name == "plmarl-forksrv" or "forkserver" in cmdline:
                    r = rollup(c.pid)
                    for k, v in r.items():
                        server[k] = max(server.get(k, 0.0), v)
            except (psutil.Error, OSError, StopIteration):
                continue
        n_max = max(n_max, n)
        if t_all is None and n_max and n == n_max and n >= 100:
            t_all = time.time() - t0
        if t_start is None:
            try:
                if "mission starts" in open(f"{run}/launcher.log").read():
                    t_start = time.time() - t0
            except OSError:
                pass
        time.sleep(2)

    def stats(key: str) -> dict[str, float]:
        v = sorted(a[key] for a in peaks.values() if key in a)
        return {"median": round(statistics.median(v), 1), "max": round(v[-1], 1)} if v else {}

    res = {"rc": p.returncode, "agents": len(peaks), "rss": stats("Rss"), "pss": stats("Pss"), "uss": stats("Uss"),
           "anon": stats("Anonymous"), "server": {k: round(v, 1) for k, v in server.items()},
           "wall_all_agents_s": t_all and round(t_all, 1), "wall_mission_starts_s": t_start and round(t_start, 1),
           "wall_total_s": round(time.time() - t0, 1)}
    json.dump({**res, "per_agent": peaks}, open(out, "w"))
    print(json.dumps(res))


if __name__ == "__main__":
    main()
