"""H-compose24, diagnosis: from a --cr-log step log, per (row, episode) of a controller and way, whether some
copy's first known failed set is not a prefix (in identity order) of the episode's full set, i.e. the copy
flew repair(P0, Y) with Y not the lowest failed identity, which the full repair does not start with.

    python docs/results/issue24/session24/compose/prefix.py cr_s7_8_steps.log "pl-marl replan"
"""
import re
import sys
from collections import Counter

sel = sys.argv[2] if len(sys.argv) > 2 else "pl-marl replan"
steps: dict = {}
sets: Counter = Counter()
for line in open(sys.argv[1]):
    m = re.match(r"(.*) ep (\d+) copy (\d+) epoch (\d+) F \[(.*)\] (.*)", line.strip())
    if m is None or sel not in m.group(1):
        continue
    f = tuple(int(x) for x in m.group(5).split(", ") if x)
    sets[f] += 1
    steps.setdefault((m.group(1), int(m.group(2))), {}).setdefault(int(m.group(3)), []).append(f)
bad = 0
for cps in steps.values():
    full = max((f for v in cps.values() for f in v), key=len)
    bad += any(v[0] != full[: len(v[0])] for v in cps.values())
print(f"{sel}: steps by failed set {dict(sorted(sets.items()))}")
print(f"{sel}: {len(steps)} episodes, {bad} with some copy whose first known set is not an identity-order prefix of the full set")
