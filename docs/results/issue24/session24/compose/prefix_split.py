"""H-compose24, information only: per episode of compose/run_steps.sh (seeds 15-18, T_up 50, replan), whether some
copy's first known failed set is not an identity-order prefix of the full set, against the paired CR - base difference.

    python docs/results/issue24/session24/compose/prefix_split.py
"""
import json
import re

import numpy as np

D = "docs/results/issue24/session24/compose"
steps: dict = {}
for line in open(f"{D}/cr_s15_18_steps.log"):
    m = re.match(r"seed (\d+) (\S+) T_up 50 (\S+) replan ep (\d+) copy (\d+) epoch (\d+) F \[(.*)\] ", line)
    if m:
        f = tuple(int(x) for x in m.group(7).split(", ") if x)
        steps.setdefault((int(m.group(1)), m.group(2), m.group(3), int(m.group(4))), {}).setdefault(int(m.group(5)), []).append(f)


def rows(p: str) -> dict:
    return {(r["seed"], r["mission"][-6:], r["controller"]): r for r in json.load(open(p))["rows"] if r["way"] == "replan"}


b, c = rows(f"{D}/base_s15_18.json"), rows(f"{D}/cr_s15_18.json")
for ctl in ("pl-marl", "service"):
    out: dict = {"non-prefix": [], "prefix only": [], "no CR step": []}
    for (s, mi, ct), r in c.items():
        if ct != ctl:
            continue
        for ep, (x, y) in enumerate(zip(b[(s, mi, ct)]["after"], r["after"], strict=True)):
            cps = steps.get((s, mi, ct, ep), {})
            if not cps:
                out["no CR step"].append(y - x)
                continue
            full = max((f for v in cps.values() for f in v), key=len)
            out["non-prefix" if any(v[0] != full[: len(v[0])] for v in cps.values()) else "prefix only"].append(y - x)
    for name, d in out.items():
        d = np.array(d)
        if len(d):
            print(f"{ctl}: {name} episodes {len(d)}, mean diff {d.mean():+.4f} (share of pooled {d.sum() / 80:+.4f}), "
                  f"wins/losses {(d > 0).sum()}/{(d < 0).sum()}")
