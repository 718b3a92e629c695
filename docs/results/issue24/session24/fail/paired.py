"""Paired per-episode differences of a variant's `replan` way against the base decomposition's.

    python docs/results/issue24/session23/fail/paired.py BASE.json VARIANT.json [CONTROLLER] [WAY]

(session 23: WAY, default `replan`, compares another way, e.g. `instant`; the greedy is the base file's.)
"""
import json
import sys

import numpy as np
from scipy import stats


def rows(path: str, ctl: str) -> dict:
    out = {}
    for r in json.load(open(path))["rows"]:
        if r["controller"] in (ctl, "greedy") and r["way"] in (way, "-"):
            out[(r["controller"], r["seed"], r["mission"].split("/")[-1])] = r
    return out


ctl = sys.argv[3] if len(sys.argv) > 3 else "service"
way = sys.argv[4] if len(sys.argv) > 4 else "replan"
base, var = rows(sys.argv[1], ctl), rows(sys.argv[2], ctl)
allb, allv, allg = [], [], []
for key in sorted(k for k in var if k[0] == ctl):
    b, v = np.array(base[key]["after"]), np.array(var[key]["after"])
    g = np.array(base[("greedy",) + key[1:]]["after"])
    allb.append(b)
    allv.append(v)
    allg.append(g)
    d = v - b
    print(f"{key[1]} {key[2]}: base {b.mean():.4f} ({b.mean() / g.mean():.3f}) variant {v.mean():.4f} ({v.mean() / g.mean():.3f}) "
          f"diff {d.mean():+.4f} wins/losses {(d > 1e-9).sum()}/{(d < -1e-9).sum()}")
b, v, g = np.concatenate(allb), np.concatenate(allv), np.concatenate(allg)
d = v - b
p = stats.wilcoxon(d).pvalue if np.any(d != 0) else 1.0
print(f"pooled ({len(d)} episodes): base {b.mean() / g.mean():.4f} variant {v.mean() / g.mean():.4f} of greedy; "
      f"diff {d.mean():+.4f} wins/losses {(d > 1e-9).sum()}/{(d < -1e-9).sum()} paired Wilcoxon p {p:.3g}")
