"""H-confirm25, criterion 3 (false declarations, per episode), written before any seed-23-26 number was read.

    python docs/results/issue24/session25/confirm/falsedecl.py BASE.json LR.json [WAY]

Per controller, paired on the same episodes (session24/local/decompose.py JSON rows, key controller, seed,
mission, T_up; episode index within the row): false_end = live UAVs declared failed at the end (summed over the
live copies, as decompose.py logs it).
  E+ = episodes where LR ends with more than the base; E- = episodes where the base ends with more than LR.
  Passes if |E+| <= |E-| + 1 and LR loses none of the E+ episodes (paired difference of the mean C(t) from
  30 s after the failure < 0 there).
Each E+ / E- episode is listed with both counts and the paired difference.
"""
import json
import sys

import numpy as np


def rows(path: str, way: str) -> dict:
    return {(r["controller"], r["seed"], r["mission"].split("/")[-1], r["tup"]): r
            for r in json.load(open(path))["rows"] if r["way"] == way}


way = sys.argv[3] if len(sys.argv) > 3 else "replan"
base, lr = rows(sys.argv[1], way), rows(sys.argv[2], way)
for ctl in ("pl-marl", "service"):
    keys = sorted(k for k in lr if k[0] == ctl and k in base)
    if not keys:
        continue
    eplus, eminus = [], []
    for k in keys:
        fb, fl = np.array(base[k]["false_end"]), np.array(lr[k]["false_end"])
        d = np.array(lr[k]["after"]) - np.array(base[k]["after"])
        for e in range(len(fb)):
            item = (k[1], k[2], k[3], e, int(fb[e]), int(fl[e]), float(d[e]))
            if fl[e] > fb[e]:
                eplus.append(item)
            elif fb[e] > fl[e]:
                eminus.append(item)
    lost = [x for x in eplus if x[6] < 0]
    ok = len(eplus) <= len(eminus) + 1 and not lost
    print(f"## `{ctl}`, way {way}: |E+| {len(eplus)}, |E-| {len(eminus)}, E+ episodes LR loses {len(lost)} -> "
          f"criterion 3 {'PASSES' if ok else 'FAILS'}")
    for name, xs in (("E+", eplus), ("E-", eminus)):
        for s, m, t, e, fb_, fl_, dd in xs:
            print(f"  {name}: seed {s} {m} T_up {t} episode {e}: declared at end base {fb_} LR {fl_}; diff {dd:+.4f}")
    print()
