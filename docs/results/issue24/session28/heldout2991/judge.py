"""Judge criteria.md (G1-G3) from bench.episodes JSON: base (missions as they are) vs new (--set transit_plan_m=50)."""
import json
import numpy as np
from scipy.stats import wilcoxon


def load(*files):
    out = {}
    for f in files:
        for r in json.load(open(f))["rows"]:
            out[(r["family"], r["tup"], r["method"])] = r["per_episode"]
    return out


base, new = load("base50.json", "base15.json"), load("new50.json", "new15.json")


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
g1 = []
for f, t in (("thin_area", 50), ("failure_transit", 15), ("failure_transit", 50)):
    d, w, l, p = cmp(new[(f, t, "pl-marl")]["coverage"], base[(f, t, "pl-marl")]["coverage"])
    g1.append(d > 0 and p < 0.01)
    print(f"G1 {f} T{t}: {d:+.4f} {w}/{l} p {p:.2g} -> {d > 0 and p < 0.01}")
print(f"G1 {'PASS' if all(g1) else 'FAIL'}")
print(f"G2 worst cell {worst:+.4f} (>= -0.002): {'PASS' if worst >= -0.002 else 'FAIL'}")
print(f"G3 false ids T15 base/new {ids[15]}, T50 {ids[50]}: {'PASS' if all(v[1] <= v[0] for v in ids.values()) else 'FAIL'}")
for name in ("dr_base.json", "dr_new.json"):
    r = {(x["family"], x["tup"], x["method"]): x["per_episode"] for x in json.load(open(name))["rows"]}
    d, w, l, p = cmp(r[("failure_transit", 50, "pl-marl")]["coverage"], r[("failure_transit", 50, "dead-reckoning")]["coverage"])
    print(f"Reported {name}: pl-marl vs dead-reckoning, failure_transit T50: {d:+.4f} {w}/{l} p {p:.2g}")
