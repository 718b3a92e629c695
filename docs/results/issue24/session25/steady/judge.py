"""H-steady25 judgement (criteria fixed in the brief before any number; written before the seed-27/28 numbers).

    python docs/results/issue24/session25/steady/judge.py CONTROLLER OUT1.json [OUT2.json ...] > judge_CONTROLLER.md

Cells = family x T_up, pooled over seeds and mission variants, paired episode by episode (base vs ops).
(1) false declarations of live UAVs over all families and T_up: primary false_ids (distinct live identities declared
    failed by a live copy, per episode), OPS total < base total; false_end / false_max / false_pairs_new beside.
(2) no cell's mean difference (ops - base) of the mean C(t), t > 50 s, below -0.003.
(3) pooled over the failure families at T_up 50, mean difference >= 0.
(4) failure_2of6 T_up 50: mean C(t) from 30 s after the failure (t >= 130 s), ratio of means to greedy's on the same episodes.
"""
import json
import sys
from collections import defaultdict

import numpy as np

ctl = sys.argv[1]
rows = [r for p in sys.argv[2:] for r in json.load(open(p))["rows"]]
key = lambda r: (r["family"], r["tup"], r["seed"], r["mission_variant"])  # noqa: E731
by = {(r["variant"],) + key(r): r for r in rows if r["controller"] == ctl}
greedy = {(r["family"], r["seed"], r["mission_variant"]): r for r in rows if r["controller"] == "greedy"}
cells = defaultdict(lambda: defaultdict(list))
for (v, fam, tup, seed, mv), r in sorted(by.items()):
    if v != "base" or ("ops", fam, tup, seed, mv) not in by:
        continue
    o = by[("ops", fam, tup, seed, mv)]
    c = cells[(fam, tup)]
    for k in ("after50", "after_fail30", "false_ids", "false_end", "false_max", "false_pairs_new"):
        c["b_" + k] += r[k]
        c["o_" + k] += o[k]
    g = greedy.get((fam, seed, mv))
    if g is not None:
        c["g_after_fail30"] += g["after_fail30"]
print(f"## `{ctl}`: base vs OPS (own-position steady test), paired episodes\n")
print("| family | T_up | episodes | base C(t>50) | OPS | diff | wins/losses/ties | false_ids base/OPS | false_end | false_max | new false pairs |")
print("|---|---|---|---|---|---|---|---|---|---|---|")
tot = defaultdict(int)
worst = (None, 1.0)
pool50 = []
for (fam, tup), c in sorted(cells.items(), key=lambda x: (x[0][1], x[0][0])):
    b, o = np.array(c["b_after50"]), np.array(c["o_after50"])
    d = o - b
    w, lo, ti = int((d > 1e-9).sum()), int((d < -1e-9).sum()), int((np.abs(d) <= 1e-9).sum())
    for k in ("false_ids", "false_end", "false_max", "false_pairs_new"):
        tot["b_" + k] += int(np.sum(c["b_" + k]))
        tot["o_" + k] += int(np.sum(c["o_" + k]))
    if d.mean() < worst[1]:
        worst = ((fam, tup), float(d.mean()))
    if tup == 50:
        pool50.append(d)
    print(f"| {fam} | {tup} | {len(d)} | {b.mean():.4f} | {o.mean():.4f} | {d.mean():+.4f} | {w}/{lo}/{ti} | "
          f"{int(np.sum(c['b_false_ids']))}/{int(np.sum(c['o_false_ids']))} | {int(np.sum(c['b_false_end']))}/{int(np.sum(c['o_false_end']))} | "
          f"{int(np.sum(c['b_false_max']))}/{int(np.sum(c['o_false_max']))} | {int(np.sum(c['b_false_pairs_new']))}/{int(np.sum(c['o_false_pairs_new']))} |")
print()
c1 = tot["o_false_ids"] < tot["b_false_ids"]
print(f"(1) false declarations, all cells: false_ids base {tot['b_false_ids']} OPS {tot['o_false_ids']} -> {'PASS' if c1 else 'FAIL'}"
      f" (false_end {tot['b_false_end']}/{tot['o_false_end']}, false_max {tot['b_false_max']}/{tot['o_false_max']}, "
      f"new false pairs {tot['b_false_pairs_new']}/{tot['o_false_pairs_new']})")
c2 = worst[1] >= -0.003
print(f"(2) worst cell {worst[0]} {worst[1]:+.4f} (bound -0.003) -> {'PASS' if c2 else 'FAIL'}")
p = np.concatenate(pool50) if pool50 else np.array([np.nan])
c3 = bool(p.mean() >= 0)
print(f"(3) pooled T_up 50 over the failure families ({p.size} episodes): diff {p.mean():+.5f}, wins/losses "
      f"{int((p > 1e-9).sum())}/{int((p < -1e-9).sum())} -> {'PASS' if c3 else 'FAIL'}")
c = cells.get(("failure_2of6", 50))
if c and c["g_after_fail30"]:
    g = np.mean(c["g_after_fail30"])
    print(f"(4) failure_2of6 T_up 50, mean C(t >= 130 s) of greedy: base {np.mean(c['b_after_fail30']) / g:.4f} "
          f"OPS {np.mean(c['o_after_fail30']) / g:.4f} (greedy {g:.4f}, base {np.mean(c['b_after_fail30']):.4f}, OPS {np.mean(c['o_after_fail30']):.4f})")
print(f"\nverdict for `{ctl}`: criteria 1-3 {'ALL PASS' if c1 and c2 and c3 else 'NOT ALL PASS'}")
