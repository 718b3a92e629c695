"""Session 24, sanity: every row of NEW.json (decompose.py) equals OLD.json's row of the same seed,
mission, T_up, controller and way, in every field they share (the greedy's included).

    python docs/results/issue24/session24/fail/same_base.py OLD.json NEW.json
"""
import json
import sys

import numpy as np


def rows(path: str) -> dict:
    return {(r["seed"], r["mission"], r["tup"], r["controller"], r["way"]): r for r in json.load(open(path))["rows"]}


old, new = rows(sys.argv[1]), rows(sys.argv[2])
bad = 0
for key, r in new.items():
    o = old[key]
    for f in sorted(set(r) & set(o)):
        same = np.array_equal(np.asarray(r[f], dtype=object), np.asarray(o[f], dtype=object)) if f not in ("all_know_s",) else \
            np.array_equal(np.array(r[f], float), np.array(o[f], float), equal_nan=True)
        if not same:
            bad += 1
            print("differs:", key, f)
print(f"{len(new)} rows compared, {bad} fields differ")
sys.exit(1 if bad else 0)
