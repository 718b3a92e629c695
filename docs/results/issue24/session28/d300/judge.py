"""Judge criteria.md (K1-K4) from bench.episodes JSON, seeds pooled (episodes paired by order)."""
import json, sys
import numpy as np
from scipy.stats import wilcoxon

SEEDS = sys.argv[1].split(",")
PRE = sys.argv[2] if len(sys.argv) > 2 else ""


def load(kind):
    out = {}
    for s in SEEDS:
        for t in ("50", "15"):
            for r in json.load(open(f"{PRE}{kind}{t}_{s}.json"))["rows"]:
                k = (r["family"], r["tup"], r["method"])
                for name, v in r["per_episode"].items():
                    out.setdefault(k, {}).setdefault(name, []).extend(v)
    return out


base, new = load("base"), load("new")


def cmp(a, b):
    d = np.array(a) - np.array(b)
    return d.mean(), int((d > 0).sum()), int((d < 0).sum()), (wilcoxon(d).pvalue if np.any(d) else 1.0)


FAIL = {"failure", "failure_random", "failure_2of6", "failure_transit", "failure_split", "diffuse_failure"}
print("| family | T_up | base | new | new - base | W/L | paired p | false ids base/new | new vs service | base vs service |")
print("|---|---|---|---|---|---|---|---|---|---|")
worst, ids = 0.0, {15: [0, 0], 50: [0, 0]}
for (f, t, m) in sorted(base):
    if m != "pl-marl":
        continue
    b, n = base[(f, t, m)], new[(f, t, m)]
    d, w, l, p = cmp(n["coverage"], b["coverage"])
    worst = min(worst, d)
    if f in FAIL:
        ids[t][0] += sum(b["false_ids"]); ids[t][1] += sum(n["false_ids"])
    sn = cmp(n["coverage"], new[(f, t, "service")]["coverage"])
    sb = cmp(b["coverage"], base[(f, t, "service")]["coverage"])
    print(f"| {f} | {t} | {np.mean(b['coverage']):.4f} | {np.mean(n['coverage']):.4f} | {d:+.4f} | {w}/{l} | {p:.2g} | "
          f"{sum(b['false_ids'])}/{sum(n['false_ids'])} | {sn[0]:+.4f} {sn[1]}/{sn[2]} p {sn[3]:.2g} | {sb[0]:+.4f} {sb[1]}/{sb[2]} p {sb[3]:.2g} |")
print()
k1 = []
for f, t in (("thin_area", 50), ("failure_transit", 15), ("failure_transit", 50)):
    d, w, l, p = cmp(new[(f, t, "pl-marl")]["coverage"], base[(f, t, "pl-marl")]["coverage"])
    k1.append(d > 0 and p < 0.01)
    print(f"K1 {f} T{t}: {d:+.4f} {w}/{l} p {p:.2g} -> {d > 0 and p < 0.01}")
print(f"K1 {'PASS' if all(k1) else 'FAIL'}")
print(f"K2 worst cell {worst:+.4f} (>= -0.002): {'PASS' if worst >= -0.002 else 'FAIL'}")
print(f"K3 false ids T15 base/new {ids[15]}, T50 {ids[50]}: {'PASS' if all(v[1] <= v[0] for v in ids.values()) else 'FAIL'}")
dr = {}
for s in SEEDS:
    for r in json.load(open(f"{PRE}dr_new_{s}.json"))["rows"]:
        dr.setdefault(r["method"], []).extend(r["per_episode"]["coverage"])
d, w, l, p = cmp(dr["pl-marl"], dr["dead-reckoning"])
print(f"K4 new pl-marl vs new dead-reckoning, failure_transit T50: {d:+.4f} {w}/{l} p {p:.2g}: {'PASS' if d > 0 and p < 0.01 else 'FAIL'}")
