"""Summarise bench.replan --json outputs: one line per (mission, T_up, way)."""
import json
import sys

for path in sys.argv[1:]:
    d = json.load(open(path))
    print(path, "seed", d["seed"], "episodes", d["episodes"])
    for r in d["rows"]:
        print(f"{r['mission'].split('/')[-1]:22s} tup {r['tup']:3d} {r['way']:14s} after {r['coverage_after_mean']:.4f}"
              f" of_greedy {r.get('of_greedy_mean', float('nan')):.4f} greedy {r.get('greedy_after_mean', float('nan')):.4f}"
              f" detect {r.get('detect_s_median')} allknow {r.get('all_know_s_median')} never {r.get('all_know_never')}"
              f" agree60 {r.get('agree_check')} agree_end {r.get('agree_end')} false_end {r.get('false_declared_end')}")
