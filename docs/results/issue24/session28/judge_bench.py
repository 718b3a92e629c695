"""Judge a `transit_plan_m` run made with `python -m plmarl_sitl.bench.episodes` (session 28): base (missions as
they are) against new (`--set transit_plan_m=...`), seeds pooled, episodes paired by order.

    python judge_bench.py DIR SEEDS LETTER [--dr-judged]

DIR holds {base,new}{50,15}_S.json and dr_new_S.json (dr_base_S.json reported when there) for each seed S of the
comma list SEEDS; LETTER names the criteria as DIR/criteria.md does (G, H or K): 1 the transit and thin-area gains,
2 the worst cell, 3 false declarations, and with --dr-judged 4 pl-marl > dead reckoning with the key (else reported)."""
import json
import os
import sys

import numpy as np
from scipy.stats import wilcoxon

DIR, SEEDS, L = sys.argv[1], sys.argv[2].split(","), sys.argv[3]
DR_JUDGED = "--dr-judged" in sys.argv
FAIL = {"failure", "failure_random", "failure_2of6", "failure_transit", "failure_split", "diffuse_failure"}


def load(kind):
    out = {}
    for s in SEEDS:
        for t in ("50", "15"):
            for r in json.load(open(f"{DIR}/{kind}{t}_{s}.json"))["rows"]:
                for name, v in r["per_episode"].items():
                    out.setdefault((r["family"], r["tup"], r["method"]), {}).setdefault(name, []).extend(v)
    return out


def cmp(a, b):
    d = np.array(a) - np.array(b)
    return d.mean(), int((d > 0).sum()), int((d < 0).sum()), (wilcoxon(d).pvalue if np.any(d) else 1.0)


def dr(kind):
    out = {}
    for s in SEEDS:
        path = f"{DIR}/dr_{kind}_{s}.json"
        if not os.path.exists(path):
            return None
        for r in json.load(open(path))["rows"]:
            out.setdefault(r["method"], []).extend(r["per_episode"]["coverage"])
    return cmp(out["pl-marl"], out["dead-reckoning"])


base, new = load("base"), load("new")
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
        ids[t][0] += sum(b["false_ids"])
        ids[t][1] += sum(n["false_ids"])
    sn = cmp(n["coverage"], new[(f, t, "service")]["coverage"])
    sb = cmp(b["coverage"], base[(f, t, "service")]["coverage"])
    print(f"| {f} | {t} | {np.mean(b['coverage']):.4f} | {np.mean(n['coverage']):.4f} | {d:+.4f} | {w}/{l} | {p:.2g} | "
          f"{sum(b['false_ids'])}/{sum(n['false_ids'])} | {sn[0]:+.4f} {sn[1]}/{sn[2]} p {sn[3]:.2g} | "
          f"{sb[0]:+.4f} {sb[1]}/{sb[2]} p {sb[3]:.2g} |")
print()
ok1 = []
for f, t in (("thin_area", 50), ("failure_transit", 15), ("failure_transit", 50)):
    d, w, l, p = cmp(new[(f, t, "pl-marl")]["coverage"], base[(f, t, "pl-marl")]["coverage"])
    ok1.append(d > 0 and p < 0.01)
    print(f"{L}1 {f} T{t}: {d:+.4f} {w}/{l} p {p:.2g} -> {d > 0 and p < 0.01}")
print(f"{L}1 {'PASS' if all(ok1) else 'FAIL'}")
print(f"{L}2 worst cell {worst:+.4f} (>= -0.002): {'PASS' if worst >= -0.002 else 'FAIL'}")
print(f"{L}3 false ids T15 base/new {ids[15]}, T50 {ids[50]}: {'PASS' if all(v[1] <= v[0] for v in ids.values()) else 'FAIL'}")
d, w, l, p = dr("new")
verdict = (": PASS" if d > 0 and p < 0.01 else ": FAIL") if DR_JUDGED else ""
print(f"{L + '4' if DR_JUDGED else 'Reported:'} pl-marl vs dead-reckoning, both with the key, failure_transit T50: "
      f"{d:+.4f} {w}/{l} p {p:.2g}{verdict}")
if (b := dr("base")) is not None:
    print(f"Reported: the same without the key: {b[0]:+.4f} {b[1]}/{b[2]} p {b[3]:.2g}")
