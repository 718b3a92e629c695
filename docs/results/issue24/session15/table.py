# ruff: noqa  (session-15 harness kept to reproduce docs/RESULTS.md; not product code)
"""Table of eval_place.py's JSONs: per family and T_up, each method's coverage, its paired
difference to `service` (wins/losses), two-sided Mann-Whitney p (what `plmarl suite` reports)
and paired Wilcoxon p against `service`, and the mean per-episode fraction of the best
reference (per episode the best of service, greedy and clairvoyant: the suite's references).

    python docs/results/issue24/session15/table.py OUT.md A.json [B.json ...]
"""
import json, sys
import numpy as np
from scipy import stats

out = sys.argv[1]
doc = {}
for p in sys.argv[2:]:
    doc.update(json.load(open(p)))
fams = list(dict.fromkeys(k.split("|")[0] for k in doc))
methods = list(dict.fromkeys(k.split("|")[1] for k in doc))
REF = ("service", "greedy", "clairvoyant")
lines = ["| family | T_up | method | coverage | - service (w/l of E) | p MWU | p Wilcoxon | frac. of best ref |", "|---|---|---|---|---|---|---|---|"]
for f in fams:
    tups = list(doc.get(f"{f}|service", {}).keys())
    for t in tups:
        have = {m: np.asarray(doc[f"{f}|{m}"][t]) for m in methods if f"{f}|{m}" in doc and t in doc[f"{f}|{m}"]}
        base = have["service"]
        refs = [have[r] for r in REF if r in have]
        best = np.max(np.stack(refs), 0)
        for m, c in have.items():
            d = c - base
            pm = stats.mannwhitneyu(c, base, alternative="two-sided").pvalue if m != "service" else float("nan")
            pw = stats.wilcoxon(c, base).pvalue if np.any(d != 0) else 1.0
            tag = " (ref: not a bound)" if m in ("greedy", "clairvoyant") else ""
            lines.append(f"| {f} | {t} | {m}{tag} | {c.mean():.4f} | {d.mean():+.4f} ({int((d>0).sum())}/{int((d<0).sum())} of {len(c)}) | "
                         f"{pm:.2g} | {pw:.2g} | {np.mean(c / np.maximum(best, 1e-9)):.3f} |")
open(out, "w").write("\n".join(lines) + "\n")
print("\n".join(lines))
