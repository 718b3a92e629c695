"""Session 23: a variant's paired difference (replan way) split by whether the base episode's heard graph split.

    python docs/results/issue24/session23/fail/split_part.py BASE.json VARIANT.json
"""
import json
import sys

import numpy as np


def rows(path: str) -> dict:
    return {(r["controller"], r["seed"], r["mission"].split("/")[-1]): r
            for r in json.load(open(path))["rows"] if r["way"] == "replan"}


base, var = rows(sys.argv[1]), rows(sys.argv[2])
for ctl in ("pl-marl", "service"):
    keys = sorted(k for k in var if k[0] == ctl)
    d = np.concatenate([np.array(var[k]["after"]) - np.array(base[k]["after"]) for k in keys])
    split = np.concatenate([np.array(base[k]["split"], bool) for k in keys])
    for name, sel in (("base split", split), ("base not split", ~split)):
        x = d[sel]
        print(f"{ctl} {name}: {sel.sum()} episodes, mean diff {x.mean():+.4f} (sum over 40: {x.sum() / len(d):+.4f}), "
              f"wins/losses {(x > 1e-9).sum()}/{(x < -1e-9).sum()}")
