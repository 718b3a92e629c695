"""H-local24, information: from an LR step log (--cr-log), per row kind (controller, way): the steps that
composed two repairs, and how often the two failed UAVs' neighbour sets (allowed rows) were disjoint
(the premise of commuting repairs); the allowed-set sizes and movers per repair.

    python docs/results/issue24/session24/local/overlap.py STEPS.log
"""
import re
import sys
from collections import Counter, defaultdict

two = defaultdict(Counter)
size, movers, fell = defaultdict(Counter), defaultdict(Counter), Counter()
for line in open(sys.argv[1]):
    kind = re.search(r"T_up \d+ (\S+ \S+) ep", line).group(1)
    if "fell back" in line:
        fell[kind] += 1
    reps = re.findall(r"(\d+): allowed \[([\d, ]*)\] movers \[([\d, ]*)\]", line)
    for _, al, mv in reps:
        size[kind][len(al.split(",")) if al else 0] += 1
        movers[kind][len(mv.split(",")) if mv else 0] += 1
    if len(reps) == 2:
        a, b = ({int(x) for x in r[1].split(",") if x} for r in reps)
        two[kind]["disjoint" if not a & b else "shared"] += 1
for kind in sorted(size):
    print(f"{kind}: repairs {sum(size[kind].values())}, allowed-set sizes {dict(sorted(size[kind].items()))}, "
          f"movers per repair {dict(sorted(movers[kind].items()))}; two-repair steps: neighbours disjoint "
          f"{two[kind]['disjoint']}, shared {two[kind]['shared']}; fell back {fell[kind]}")
