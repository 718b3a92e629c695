"""smaps breakdown of a pid (or self): Rss/Pss/Anon by mapping name, top entries."""
import sys, collections, os
def breakdown(pid="self", top=15):
    agg = collections.defaultdict(lambda: [0, 0, 0])
    name = None
    for line in open(f"/proc/{pid}/smaps"):
        parts = line.split()
        if not parts[0].endswith(":") or len(parts[0]) > 20 and "-" in parts[0]:
            pass
        if "-" in parts[0] and not parts[0].endswith(":"):
            name = parts[5] if len(parts) > 5 else "[anon]"
            name = os.path.basename(name) if name.startswith("/") else name
            continue
        if parts[0] == "Rss:": agg[name][0] += int(parts[1])
        elif parts[0] == "Pss:": agg[name][1] += int(parts[1])
        elif parts[0] == "Anonymous:": agg[name][2] += int(parts[1])
    tot = [sum(v[i] for v in agg.values()) for i in range(3)]
    rows = sorted(agg.items(), key=lambda kv: -kv[1][0])[:top]
    return tot, rows
if __name__ == "__main__":
    tot, rows = breakdown(sys.argv[1] if len(sys.argv) > 1 else "self")
    print("total Rss %.1f Pss %.1f Anon %.1f MB" % tuple(x/1024 for x in tot))
    for n, v in rows: print("  %-40s Rss %7.1f Pss %7.1f Anon %7.1f" % (n[:40], *(x/1024 for x in v)))
