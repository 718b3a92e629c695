"""usage: wss.py SECONDS PID...: clear each process's referenced bits (`echo 1 > clear_refs`), wait,
then print its Rss and Referenced by mapping from smaps: what it touched in that time (its working
set) against what it holds. Session 15, issue 24.2."""
import collections
import os
import sys
import time


def main() -> None:
    secs, pids = float(sys.argv[1]), sys.argv[2:]
    for p in pids:
        with open(f"/proc/{p}/clear_refs", "w") as f:
            f.write("1")
    time.sleep(secs)
    for p in pids:
        agg: collections.Counter = collections.Counter()
        name = None
        with open(f"/proc/{p}/smaps") as f:
            for line in f:
                parts = line.split()
                if not parts[0].endswith(":"):
                    name = parts[5] if len(parts) > 5 else "[anon]"
                    name = os.path.basename(name) if name.startswith("/") else name
                elif parts[0] in ("Rss:", "Referenced:", "Anonymous:"):
                    agg[(name, parts[0][:-1])] += int(parts[1])
        total: collections.Counter = collections.Counter()
        for (_, k), v in agg.items():
            total[k] += v
        with open(f"/proc/{p}/comm") as f:
            comm = f.read().strip()
        print(f"{comm} Rss {total['Rss'] / 1024:.1f} Referenced {total['Referenced'] / 1024:.1f} Anonymous {total['Anonymous'] / 1024:.1f} MB")
        for n in sorted({n for n, _ in agg}, key=lambda n: -agg[(n, "Rss")])[:8]:
            print(f"   {n[:30]:30s} Rss {agg[(n, 'Rss')] / 1024:6.1f} Referenced {agg[(n, 'Referenced')] / 1024:6.1f}")


if __name__ == "__main__":
    main()
