"""H-trace24: the base's split episodes under decompose.py's `spread` way (every survivor's knowledge merged before
each decision, detection as the product's): does the split go when the copies cannot differ, and how the base's
`instant` - `replan` loss splits into spreading (`spread` - `replan`) and detection (`instant` - `spread`) per class.

    python docs/results/issue24/session24/trace/spread_cmp.py trace_s7_14.json trace_spread_s7_14.json
"""
import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from classify import greedy_of, klass

base = json.loads(Path(sys.argv[1]).read_text())["rows"]
spr = {(r["seed"], r["mission"], r["episode"]): r for r in json.loads(Path(sys.argv[2]).read_text())["rows"]}
g = greedy_of()
gmean = float(np.mean([x for v in g.values() for x in v]))
n = len(base)
print(f"spread: {np.mean([r['after'] for r in spr.values()]) / gmean:.4f} of greedy; split episodes {sum(bool(r['split_instants']) for r in spr.values())} of {len(spr)}")
by = defaultdict(list)
for r in base:
    s = spr[(r["seed"], r["mission"], r["episode"])]
    k = klass(r)[0] if r["split_instants"] else "no split"
    by[k].append((r["after"], s["after"], r["instant"], bool(s["split_instants"])))
print("| base class | episodes | split under spread | spreading (spread - replan), pooled over 160, of greedy | detection (instant - spread), pooled |")
print("|---|---|---|---|---|")
for k, v in sorted(by.items()):
    a = np.array([x[:3] for x in v])
    print(f"| {k} | {len(v)} | {sum(x[3] for x in v)} | {(a[:, 1] - a[:, 0]).sum() / n / gmean:.4f} | {(a[:, 2] - a[:, 1]).sum() / n / gmean:.4f} |")
a = np.array([[r["after"], spr[(r["seed"], r["mission"], r["episode"])]["after"], r["instant"]] for r in base])
print(f"| all | {n} | {sum(bool(r['split_instants']) for r in spr.values())} | {(a[:, 1] - a[:, 0]).sum() / n / gmean:.4f} | {(a[:, 2] - a[:, 1]).sum() / n / gmean:.4f} |")
