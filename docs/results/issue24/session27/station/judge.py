"""Session 27 judgement of local repairs on station (criteria.md, fixed before any number; this script written before
the seed-35/36 numbers were read).

    python docs/results/issue24/session27/station/judge.py OUT1.json [OUT2.json ...] > judge.md

Cells = family x T_up, pooled over seeds and mission variants, paired episode by episode: candidate
(`pl-marl-local-repairs`, variant lrs) minus default (`pl-marl`, variant hl); also the ungated local repairs
(`pl-marl-local-repairs`, hl) minus the default, for information.
"""
import json
import sys
from collections import defaultdict

import numpy as np

rows = [r for p in sys.argv[1:] for r in json.load(open(p))["rows"]]
key = lambda r: (r["family"], r["tup"], r["seed"], r["mission_variant"])  # noqa: E731
by = {(r["controller"], r["variant"]) + key(r): r for r in rows}
DEF, CAND, LR = ("pl-marl", "hl"), ("pl-marl-local-repairs", "lrs"), ("pl-marl-local-repairs", "hl")
greedy = {(r["family"], r["seed"], r["mission_variant"]): r for r in rows if r["controller"] == "greedy"}
cells = defaultdict(lambda: defaultdict(list))
for k, r in sorted(by.items()):
    if k[:2] != DEF or CAND + k[2:] not in by:
        continue
    fam, tup, seed, mv = k[2:]
    c = cells[(fam, tup)]
    for name, v in (("d", r), ("c", by[CAND + k[2:]]), ("l", by.get(LR + k[2:]))):
        if v is None:
            continue
        for f in ("after50", "after_fail30", "false_ids", "false_end", "undeclared_end"):
            c[f"{name}_{f}"] += v[f]
    g = greedy.get((fam, seed, mv))
    if g is not None:
        c["g_after_fail30"] += g["after_fail30"]


def wlt(d: np.ndarray) -> str:
    return f"{int((d > 1e-9).sum())}/{int((d < -1e-9).sum())}/{int((np.abs(d) <= 1e-9).sum())}"


print("## local repairs on station (lrs) against the default re-solve (hl), `pl-marl`, paired episodes\n")
print("| family | T_up | episodes | default C(t>50) | lrs | lrs - default (W/L/T) | lr (ungated) - default (W/L/T) | after failure +30 s: default | lrs | false_ids default/lrs/lr | false_end | undeclared at end |")
print("|---|---|---|---|---|---|---|---|---|---|---|---|")
tot = defaultdict(int)
diffs = {}
for (fam, tup), c in sorted(cells.items(), key=lambda x: (-x[0][1], x[0][0])):
    b, o = np.array(c["d_after50"]), np.array(c["c_after50"])
    d = o - b
    diffs[(fam, tup)] = d
    lr = f"{(np.array(c['l_after50']) - b).mean():+.4f} ({wlt(np.array(c['l_after50']) - b)})" if c["l_after50"] else "-"
    if tup == 50:
        for x in ("d", "c", "l"):
            tot[x] += int(np.sum(c[f"{x}_false_ids"]))
    print(f"| {fam} | {tup} | {len(d)} | {b.mean():.4f} | {o.mean():.4f} | {d.mean():+.4f} ({wlt(d)}) | {lr} | "
          f"{np.mean(c['d_after_fail30']):.4f} | {np.mean(c['c_after_fail30']):.4f} | "
          f"{int(np.sum(c['d_false_ids']))}/{int(np.sum(c['c_false_ids']))}/{int(np.sum(c['l_false_ids'])) if c['l_false_ids'] else '-'} | "
          f"{int(np.sum(c['d_false_end']))}/{int(np.sum(c['c_false_end']))} | {int(np.sum(c['d_undeclared_end']))}/{int(np.sum(c['c_undeclared_end']))} |")
print()
d = diffs.get(("failure_2of6", 50), np.zeros(1))
l1 = bool(d.mean() >= 0.004 and (d > 1e-9).sum() > (d < -1e-9).sum())
print(f"L1 failure_2of6 T_up 50: {d.mean():+.4f} ({wlt(d)}) (>= +0.004, wins > losses) -> {'PASS' if l1 else 'FAIL'}")
worst = min(diffs.items(), key=lambda x: x[1].mean())
l2 = bool(worst[1].mean() >= -0.003)
print(f"L2 worst cell {worst[0]} {worst[1].mean():+.4f} (bound -0.003) -> {'PASS' if l2 else 'FAIL'}")
tr = {t: diffs[("failure_transit", t)].mean() for t in (15, 50) if ("failure_transit", t) in diffs}
l3 = all(v >= -0.002 for v in tr.values()) and len(tr) == 2
print(f"L3 failure_transit: " + ", ".join(f"T_up {t} {v:+.4f}" for t, v in tr.items()) + f" (each >= -0.002) -> {'PASS' if l3 else 'FAIL'}")
bound = max(1.5 * tot["d"], tot["d"] + 5)
l4 = tot["c"] <= bound
print(f"L4 false_ids at T_up 50: default {tot['d']} lrs {tot['c']} (lr {tot['l']}; bound {bound:g}) -> {'PASS' if l4 else 'FAIL'}")
for tup in (50, 15):
    c = cells.get(("failure_2of6", tup))
    if c and c["g_after_fail30"]:
        g = np.mean(c["g_after_fail30"])
        print(f"report: failure_2of6 T_up {tup}, mean C(t >= 130 s) of greedy: default {np.mean(c['d_after_fail30']) / g:.4f} "
              f"lrs {np.mean(c['c_after_fail30']) / g:.4f} (greedy {g:.4f})")
print(f"\nverdict: L1-L4 {'ALL PASS: confirmed' if l1 and l2 and l3 and l4 else 'NOT ALL PASS: not confirmed'}")
