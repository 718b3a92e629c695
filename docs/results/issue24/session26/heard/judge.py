"""Session 26 judgement of the heard-link declaration (criteria.md, fixed before any number; this script written
before the seed-32/33 numbers were read, from session 25's steady/judge.py).

    python docs/results/issue24/session26/heard/judge.py OUT1.json [OUT2.json ...] > judge.md

Cells = family x T_up, pooled over seeds and mission variants, paired episode by episode (base vs hl), `pl-marl`.
K1 failure_2of6 T_up 50: hl - base > 0 (mean C(t), t > 50 s) with wins > 2 x losses.
K2 no cell below -0.003.
K3 false_ids over all cells: hl <= max(1.5 x base, base + 5).
Report: undeclared failures at the end; failure_2of6 T_up 50 of greedy from 30 s after the failure.
"""
import json
import sys
from collections import defaultdict

import numpy as np

rows = [r for p in sys.argv[1:] for r in json.load(open(p))["rows"]]
key = lambda r: (r["family"], r["tup"], r["seed"], r["mission_variant"])  # noqa: E731
by = {(r["variant"],) + key(r): r for r in rows if r["controller"] == "pl-marl"}
greedy = {(r["family"], r["seed"], r["mission_variant"]): r for r in rows if r["controller"] == "greedy"}
cells = defaultdict(lambda: defaultdict(list))
for (v, fam, tup, seed, mv), r in sorted(by.items()):
    if v != "base" or ("hl", fam, tup, seed, mv) not in by:
        continue
    o = by[("hl", fam, tup, seed, mv)]
    c = cells[(fam, tup)]
    for k in ("after50", "after_fail30", "false_ids", "false_end", "undeclared_end", "detect_s"):
        c["b_" + k] += r[k]
        c["o_" + k] += o[k]
    g = greedy.get((fam, seed, mv))
    if g is not None:
        c["g_after_fail30"] += g["after_fail30"]
print("## `pl-marl`: base vs heard-link declaration (hl), paired episodes\n")
print("| family | T_up | episodes | base C(t>50) | hl | diff | wins/losses/ties | after failure +30 s: base | hl | diff | false_ids base/hl | false_end | undeclared at end | detect s (mean) |")
print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
tot = defaultdict(int)
worst = (None, 1.0)
for (fam, tup), c in sorted(cells.items(), key=lambda x: (-x[0][1], x[0][0])):
    b, o = np.array(c["b_after50"]), np.array(c["o_after50"])
    d = o - b
    ba, oa = np.array(c["b_after_fail30"]), np.array(c["o_after_fail30"])
    w, lo, ti = int((d > 1e-9).sum()), int((d < -1e-9).sum()), int((np.abs(d) <= 1e-9).sum())
    for k in ("false_ids", "false_end", "undeclared_end"):
        tot["b_" + k] += int(np.sum(c["b_" + k]))
        tot["o_" + k] += int(np.sum(c["o_" + k]))
    if d.mean() < worst[1]:
        worst = ((fam, tup), float(d.mean()))
    print(f"| {fam} | {tup} | {len(d)} | {b.mean():.4f} | {o.mean():.4f} | {d.mean():+.4f} | {w}/{lo}/{ti} | "
          f"{ba.mean():.4f} | {oa.mean():.4f} | {(oa - ba).mean():+.4f} | "
          f"{int(np.sum(c['b_false_ids']))}/{int(np.sum(c['o_false_ids']))} | {int(np.sum(c['b_false_end']))}/{int(np.sum(c['o_false_end']))} | "
          f"{int(np.sum(c['b_undeclared_end']))}/{int(np.sum(c['o_undeclared_end']))} | "
          f"{np.nanmean(c['b_detect_s']):.1f}/{np.nanmean(c['o_detect_s']):.1f} |")
print()
c = cells.get(("failure_2of6", 50))
k1 = False
if c:
    d = np.array(c["o_after50"]) - np.array(c["b_after50"])
    w, lo = int((d > 1e-9).sum()), int((d < -1e-9).sum())
    k1 = bool(d.mean() > 0 and w > 2 * lo)
    print(f"K1 failure_2of6 T_up 50: diff {d.mean():+.4f}, wins/losses {w}/{lo} -> {'PASS' if k1 else 'FAIL'}")
k2 = worst[1] >= -0.003
print(f"K2 worst cell {worst[0]} {worst[1]:+.4f} (bound -0.003) -> {'PASS' if k2 else 'FAIL'}")
bound = max(1.5 * tot["b_false_ids"], tot["b_false_ids"] + 5)
k3 = tot["o_false_ids"] <= bound
print(f"K3 false_ids base {tot['b_false_ids']} hl {tot['o_false_ids']} (bound {bound:g}) -> {'PASS' if k3 else 'FAIL'}"
      f" (false_end {tot['b_false_end']}/{tot['o_false_end']}; undeclared at end {tot['b_undeclared_end']}/{tot['o_undeclared_end']})")
if c and c["g_after_fail30"]:
    g = np.mean(c["g_after_fail30"])
    print(f"report: failure_2of6 T_up 50, mean C(t >= 130 s) of greedy: base {np.mean(c['b_after_fail30']) / g:.4f} "
          f"hl {np.mean(c['o_after_fail30']) / g:.4f} (greedy {g:.4f})")
print(f"\nverdict: K1-K3 {'ALL PASS: confirmed' if k1 and k2 and k3 else 'NOT ALL PASS: not confirmed'}")
