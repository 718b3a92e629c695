"""Judge criteria.md (C1-C4) from the runner's JSON (pooled over seeds, paired by episode)."""
import json, sys
import numpy as np
from scipy.stats import wilcoxon

rows = []
for f in sys.argv[1:]:
    rows += json.load(open(f))
cells = {}
for r in rows:
    cells.setdefault((r["family"], r["tup"], r["method"]), {"cov": [], "ids": [], "after": []})
    c = cells[(r["family"], r["tup"], r["method"])]
    c["cov"] += r["cov"]; c["ids"] += r["false_ids"]; c["after"] += r.get("after_fail30", [])
A = lambda k: np.array(cells[k]["cov"])


def cmp(a, b):
    d = A(a) - A(b)
    p = wilcoxon(d).pvalue if np.any(d) else 1.0
    return d.mean(), int((d > 0).sum()), int((d < 0).sum()), p


NEW, BASE = "pl-marl@transit50", "pl-marl"
print("| family | T_up | base | new | new - base | W/L | paired p | false ids base/new |")
print("|---|---|---|---|---|---|---|---|")
worst, ok = 0.0, True
fams = sorted({(f, t) for f, t, m in cells if m == NEW})
for f, t in fams:
    d, w, l, p = cmp((f, t, NEW), (f, t, BASE))
    worst = min(worst, d)
    print(f"| {f} | {t} | {A((f,t,BASE)).mean():.4f} | {A((f,t,NEW)).mean():.4f} | {d:+.4f} | {w}/{l} | {p:.2g} | "
          f"{sum(cells[(f,t,BASE)]['ids'])}/{sum(cells[(f,t,NEW)]['ids'])} |")
print()
c1a = all(cmp(("failure_transit", t, NEW), ("failure_transit", t, BASE))[0] >= 0 for t in (15, 50) if ("failure_transit", t, NEW) in cells)
d, w, l, p = cmp(("failure_transit", 50, NEW), ("failure_transit", 50, "service"))
c1b = d > 0 and p < 0.01
print(f"C1: transit new-base >= 0 at 15 and 50: {c1a}; new vs service T50: {d:+.4f} {w}/{l} p {p:.2g} -> {c1b}; C1 {'PASS' if c1a and c1b else 'FAIL'}")
print(f"C2: worst cell new - base {worst:+.4f} (>= -0.002): {'PASS' if worst >= -0.002 else 'FAIL'}")
failfams = {"failure", "failure_random", "failure_2of6", "failure_transit", "failure_split", "diffuse_failure"}
c3 = True
for t in (15, 50):
    b = sum(sum(cells[(f, t, BASE)]["ids"]) for f in failfams if (f, t, BASE) in cells)
    n = sum(sum(cells[(f, t, NEW)]["ids"]) for f in failfams if (f, t, NEW) in cells)
    c3 &= n <= b
    print(f"C3: T_up {t}: false ids base {b}, new {n}")
print(f"C3 {'PASS' if c3 else 'FAIL'}")
d, w, l, p = cmp(("failure_transit", 50, NEW), ("failure_transit", 50, "dead-reckoning@transit50"))
print(f"C4: new vs dead-reckoning@transit50, transit T50: {d:+.4f} {w}/{l} p {p:.2g}: {'PASS' if d > 0 and p < 0.01 else 'FAIL'}")
print()
print("Reported: pl-marl (new) vs service, failure families")
for f, t in fams:
    if f in failfams and (f, t, "service") in cells:
        for m in (NEW, BASE):
            d, w, l, p = cmp((f, t, m), (f, t, "service"))
            print(f"  {f} T{t} {m} vs service: {d:+.4f} {w}/{l} p {p:.2g}")
