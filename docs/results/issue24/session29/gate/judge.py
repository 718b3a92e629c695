"""Judge session 29's gate experiment (criteria.md): base (v0_*) against gate (v1_*), seeds pooled, episodes
paired by order. `python judge.py DIR SEEDS [BASE GATE]` (defaults v0 v1)."""
import json
import sys

import numpy as np
from scipy.stats import wilcoxon

DIR, SEEDS = sys.argv[1], sys.argv[2].split(",")
BASE, GATE = (sys.argv[3], sys.argv[4]) if len(sys.argv) > 4 else ("v0", "v1")
FAIL = {"failure", "failure_random", "failure_2of6", "failure_transit", "failure_split", "diffuse_failure"}


def load(kind):
    out = {}
    for s in SEEDS:
        for t in ("50", "15"):
            for r in json.load(open(f"{DIR}/{kind}_{t}_{s}.json"))["rows"]:
                for name, v in r["per_episode"].items():
                    out.setdefault((r["family"], r["tup"], r["method"]), {}).setdefault(name, []).extend(v)
    return out


def cmp(a, b):
    d = np.array(a, dtype=float) - np.array(b, dtype=float)
    return d.mean(), int((d > 0).sum()), int((d < 0).sum()), (wilcoxon(d).pvalue if np.any(d) else 1.0)


base, gate = load(BASE), load(GATE)
print("| family | T_up | pl-marl base | gate - base | W/L | p | service gate - base | p | gate: pl-marl - service | gate: pl-marl - DR | p | false ids base/gate |")
print("|---|---|---|---|---|---|---|---|---|---|---|---|")
worst, ids = (0.0, None), {15: [0, 0], 50: [0, 0]}
res = {}
for (f, t, m) in sorted(base):
    if m != "pl-marl":
        continue
    b, g = base[(f, t, m)], gate[(f, t, m)]
    d, w, l, p = cmp(g["coverage"], b["coverage"])
    res[(f, t)] = (d, p)
    if d < worst[0]:
        worst = (d, (f, t))
    sd, _, _, sp = cmp(gate[(f, t, "service")]["coverage"], base[(f, t, "service")]["coverage"])
    vs, _, _, _ = cmp(g["coverage"], gate[(f, t, "service")]["coverage"])
    dr = cmp(g["coverage"], gate[(f, t, "dead-reckoning")]["coverage"])
    fb, fg = sum(b["false_ids"]), sum(g["false_ids"])
    if f in FAIL:
        ids[t][0] += fb
        ids[t][1] += fg
    print(f"| {f} | {t} | {np.mean(b['coverage']):.4f} | {d:+.4f} | {w}/{l} | {p:.2g} | {sd:+.4f} | {sp:.2g} | {vs:+.4f} | "
          f"{dr[0]:+.4f} ({dr[1]}/{dr[2]}) | {dr[3]:.2g} | {fb}/{fg} |")
c1 = res[("thin_area", 50)]
dr = cmp(gate[("failure_transit", 50, "pl-marl")]["coverage"], gate[("failure_transit", 50, "dead-reckoning")]["coverage"])
print(f"\nC1 thin_area T50 gate - base {c1[0]:+.4f} p {c1[1]:.2g}: {'pass' if c1[0] > 0 and c1[1] < 0.01 else 'FAIL'}")
print(f"C2 failure_transit T50 gate pl-marl - DR {dr[0]:+.4f} ({dr[1]}/{dr[2]}) p {dr[3]:.2g}: "
      f"{'pass' if dr[0] > 0 and dr[3] < 0.01 else 'FAIL'}")
print(f"C3 worst cell {worst[0]:+.4f} at {worst[1]}: {'pass' if worst[0] >= -0.002 else 'FAIL'}")
print(f"C4 live UAVs declared failed (failure families) base/gate: T15 {ids[15][0]}/{ids[15][1]}, T50 {ids[50][0]}/{ids[50][1]}: "
      f"{'pass' if all(g <= b for b, g in ids.values()) else 'FAIL'}")
