"""Session 22 (used again in session 23): the variants against the base on the same 40 episodes (seeds 7, 8; decompose.py JSON, `replan` way).

    python docs/results/issue24/session23/fail/table.py BASE.json NAME=VARIANT.json ...
"""
import json
import sys

import numpy as np
from scipy import stats


def rows(path: str) -> dict:
    return {(r["controller"], r["seed"], r["mission"].split("/")[-1]): r
            for r in json.load(open(path))["rows"] if r["way"] in ("replan", "-")}


base = rows(sys.argv[1])
print("| variant | controller | of greedy | diff to base | wins/losses (of 40) | paired Wilcoxon p | never | split | live declared: max during (sum) / at the end (sum) |")
print("|---|---|---|---|---|---|---|---|---|")
for ctl in ("pl-marl", "service"):
    for arg in ["base=" + sys.argv[1], *sys.argv[2:]]:
        name, path = arg.split("=", 1)
        var = rows(path)
        keys = sorted(k for k in var if k[0] == ctl)
        if not keys:
            continue
        b = np.concatenate([base[k]["after"] for k in keys])
        v = np.concatenate([var[k]["after"] for k in keys])
        g = np.concatenate([base[("greedy",) + k[1:]]["after"] for k in keys])
        d = v - b
        p = stats.wilcoxon(d).pvalue if np.any(d != 0) else float("nan")
        never = sum(int(np.isnan(np.array(var[k]["all_know_s"], dtype=float)).sum()) for k in keys)
        split = sum(int(np.sum(var[k]["split"])) for k in keys)
        fmax = sum(int(np.sum(var[k]["false_max"])) for k in keys)
        fend = sum(int(np.sum(var[k]["false_end"])) for k in keys)
        diff = "" if name == "base" else f"{d.mean():+.4f}"
        wl = "" if name == "base" else f"{(d > 1e-9).sum()}/{(d < -1e-9).sum()}"
        pp = "" if name == "base" else f"{p:.3g}"
        print(f"| {name} | `{ctl}` | {v.mean() / g.mean():.4f} | {diff} | {wl} | {pp} | {never} | {split} | {fmax} / {fend} |")
