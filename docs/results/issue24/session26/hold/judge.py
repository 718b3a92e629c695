"""H-hold26 judgement (criteria fixed in the brief and the README before any number).

    python docs/results/issue24/session26/hold/judge.py OUT1.json [OUT2.json ...] > judge.md

Cells = family x T_up, pooled over seeds and mission variants, paired episode by episode; score: mean C(t), t > 50 s.
C1: false_ids (distinct live UAVs declared failed by a live copy, per episode) summed over the families at T_up 50:
    lr_hold < lr.
C2: failure_transit T_up 50: mean (lr_hold - lr) >= +0.004.
C3: no cell's mean (lr_hold - base) below -0.003.
C4: failure_2of6 T_up 50: mean (lr_hold - base) > 0 and wins > 2 x losses.
Beside: failure_2of6 T_up 50 C(t >= fail_s + 30) of greedy (ratio of means), detect_s lr vs lr_hold, held pairs.
"""
import json
import sys
from collections import defaultdict

import numpy as np

rows = [r for p in sys.argv[1:] for r in json.load(open(p))["rows"]]
V = ("base", "lr", "lr_hold")
by = {(r["variant"], r["family"], r["tup"], r["seed"], r["mission_variant"]): r for r in rows if r["controller"] == "pl-marl"}
greedy = {(r["family"], r["seed"], r["mission_variant"]): r for r in rows if r["controller"] == "greedy"}
cells = defaultdict(lambda: defaultdict(list))
for (v, fam, tup, seed, mv), r in sorted(by.items()):
    if v != "base" or not all((w, fam, tup, seed, mv) in by for w in V):
        continue
    c = cells[(fam, tup)]
    for w in V:
        x = by[(w, fam, tup, seed, mv)]
        for k in ("after50", "after_fail30", "false_ids", "false_end", "false_max", "false_pairs_new", "detect_s",
                  "dead_end", "dead_declared", "held_live", "held_dead"):
            c[w + ":" + k] += x[k]
    g = greedy.get((fam, seed, mv))
    if g is not None:
        c["greedy:after_fail30"] += g["after_fail30"]


def wlt(d: np.ndarray) -> str:
    return f"{int((d > 1e-9).sum())}/{int((d < -1e-9).sum())}/{int((np.abs(d) <= 1e-9).sum())}"


A = lambda c, w, k: np.array(c[w + ":" + k], dtype=float)  # noqa: E731
print("## `pl-marl`: base (re-solve) vs lr (local repairs) vs lr_hold (local repairs + HOLD), paired episodes\n")
print("| family | T_up | episodes | base | lr | lr_hold | lr_hold - lr (W/L/T) | lr_hold - base (W/L/T) | lr - base | "
      "false_ids base/lr/lr_hold | false_end b/lr/lh | held live/dead | detect_s lr / lr_hold | dead declared lr/lh of dead |")
print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
tot = defaultdict(int)
worst = (None, 1.0)
res = {}
for (fam, tup), c in sorted(cells.items(), key=lambda x: (-x[0][1], x[0][0])):
    b, l, h = A(c, "base", "after50"), A(c, "lr", "after50"), A(c, "lr_hold", "after50")
    dhl, dhb, dlb = h - l, h - b, l - b
    res[(fam, tup)] = (dhl, dhb)
    fi = [int(A(c, w, "false_ids").sum()) for w in V]
    fe = [int(A(c, w, "false_end").sum()) for w in V]
    if tup == 50:
        for w, x in zip(V, fi, strict=True):
            tot[w] += x
    if dhb.mean() < worst[1]:
        worst = ((fam, tup), float(dhb.mean()))
    dl, dh = A(c, "lr", "detect_s"), A(c, "lr_hold", "detect_s")
    print(f"| {fam} | {tup} | {len(b)} | {b.mean():.4f} | {l.mean():.4f} | {h.mean():.4f} | {dhl.mean():+.4f} ({wlt(dhl)}) | "
          f"{dhb.mean():+.4f} ({wlt(dhb)}) | {dlb.mean():+.4f} ({wlt(dlb)}) | {fi[0]}/{fi[1]}/{fi[2]} | {fe[0]}/{fe[1]}/{fe[2]} | "
          f"{int(A(c, 'lr_hold', 'held_live').sum())}/{int(A(c, 'lr_hold', 'held_dead').sum())} | "
          f"{np.nanmean(dl):.2f} / {np.nanmean(dh):.2f} | {int(A(c, 'lr', 'dead_declared').sum())}/"
          f"{int(A(c, 'lr_hold', 'dead_declared').sum())} of {int(A(c, 'lr', 'dead_end').sum())} |")
print()
c1 = tot["lr_hold"] < tot["lr"]
print(f"C1 false_ids at T_up 50 (all families): base {tot['base']} lr {tot['lr']} lr_hold {tot['lr_hold']} -> {'PASS' if c1 else 'FAIL'}")
c2v = res.get(("failure_transit", 50), (np.array([np.nan]),))[0]
c2 = bool(c2v.mean() >= 0.004)
print(f"C2 failure_transit T_up 50 lr_hold - lr {c2v.mean():+.4f} ({wlt(c2v)}) (>= +0.004) -> {'PASS' if c2 else 'FAIL'}")
c3 = worst[1] >= -0.003
print(f"C3 worst cell lr_hold - base {worst[0]} {worst[1]:+.4f} (bound -0.003) -> {'PASS' if c3 else 'FAIL'}")
c4v = res.get(("failure_2of6", 50), (None, np.array([np.nan])))[1]
w4, l4 = int((c4v > 1e-9).sum()), int((c4v < -1e-9).sum())
c4 = bool(c4v.mean() > 0 and w4 > 2 * l4)
print(f"C4 failure_2of6 T_up 50 lr_hold - base {c4v.mean():+.4f}, wins/losses {w4}/{l4} (> 0 and wins > 2 x losses) -> {'PASS' if c4 else 'FAIL'}")
c = cells.get(("failure_2of6", 50))
if c and c["greedy:after_fail30"]:
    g = np.mean(c["greedy:after_fail30"])
    print("failure_2of6 T_up 50, C(t >= fail_s + 30) of greedy: " + ", ".join(
        f"{w} {A(c, w, 'after_fail30').mean() / g:.4f}" for w in V) + f" (greedy {g:.4f})")
dl = np.concatenate([A(c, "lr", "detect_s") for c in cells.values()])
dh = np.concatenate([A(c, "lr_hold", "detect_s") for c in cells.values()])
both = np.isfinite(dl) & np.isfinite(dh)
print(f"true declarations' delay (detect_s, mean over episodes with a declared dead UAV in both, {int(both.sum())} episodes): "
      f"lr {dl[both].mean():.2f} s, lr_hold {dh[both].mean():.2f} s; episodes later / earlier / same "
      f"{int((dh[both] > dl[both] + 1e-9).sum())}/{int((dh[both] < dl[both] - 1e-9).sum())}/{int((np.abs(dh[both] - dl[both]) <= 1e-9).sum())}")
print(f"\nverdict: C1-C4 {'ALL PASS: confirmed' if c1 and c2 and c3 and c4 else 'NOT ALL PASS: not confirmed'}")
