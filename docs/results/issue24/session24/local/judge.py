"""H-local24: local repairs (LR; H-compose24's compose/judge.py, CR renamed LR, plus movers) against the base,
paired on the same episodes (local/decompose.py JSON). the column "fell back / LR steps" counts
(the copies' failure re-plan steps that took the local (composable) repairs, and those that fell back to the full re-solve).

    python docs/results/issue24/session24/local/judge.py BASE.json LR.json [WAY]

Per controller: of-greedy fractions (base, LR; ratio of the means over the same episodes), the pooled
paired difference, wins/losses (identical episodes are ties, neither), paired Wilcoxon p, `never` and
`split` counts, live UAVs declared at the end, LR's fall-backs (of all copies' failure re-plan steps), per cell, and
split against other episodes (the base's split).
"""
import json
import sys

import numpy as np
from scipy import stats


def rows(path: str, way: str) -> dict:
    return {(r["controller"], r["seed"], r["mission"].split("/")[-1], r["tup"]): r
            for r in json.load(open(path))["rows"] if r["way"] in (way, "-")}


way = sys.argv[3] if len(sys.argv) > 3 else "replan"
base, sg = rows(sys.argv[1], way), rows(sys.argv[2], way)
for ctl in ("pl-marl", "service"):
    keys = sorted(k for k in sg if k[0] == ctl)
    if not keys:
        continue
    print(f"## `{ctl}`, way {way}")
    print("| cell | base of greedy | LR of greedy | diff | wins/losses | fell back / LR steps | split base -> LR |")
    print("|---|---|---|---|---|---|---|")
    cols = {n: [] for n in ("b", "v", "g", "split", "fired", "steps")}
    for k in keys:
        b, v = np.array(base[k]["after"]), np.array(sg[k]["after"])
        g = np.array(base[("greedy",) + k[1:]]["after"])
        d = v - b
        fired, steps = np.array(sg[k]["cr_fallback"]), np.array(sg[k]["cr_steps"])
        for n, x in (("b", b), ("v", v), ("g", g), ("split", np.array(base[k]["split"], bool)), ("fired", fired), ("steps", steps)):
            cols[n].append(x)
        print(f"| {k[1]} {k[2]} T_up {k[3]} | {b.mean() / g.mean():.4f} | {v.mean() / g.mean():.4f} | {d.mean():+.4f} | "
              f"{(d > 0).sum()}/{(d < 0).sum()} | {fired.sum()}/{steps.sum()} | {int(np.sum(base[k]['split']))} -> {int(np.sum(sg[k]['split']))} |")
    b, v, g, split, fired, steps = (np.concatenate(cols[n]) for n in ("b", "v", "g", "split", "fired", "steps"))
    d = v - b
    p = stats.wilcoxon(d).pvalue if np.any(d != 0) else float("nan")
    w, lo = int((d > 0).sum()), int((d < 0).sum())
    never = [sum(int(np.isnan(np.array(r[k]["all_know_s"], dtype=float)).sum()) for k in keys) for r in (base, sg)]
    nsplit = [sum(int(np.sum(r[k]["split"])) for k in keys) for r in (base, sg)]
    fend = [sum(int(np.sum(r[k]["false_end"])) for k in keys) for r in (base, sg)]
    fmax = [sum(int(np.sum(r[k]["false_max"])) for k in keys) for r in (base, sg)]
    print(f"\npooled ({len(d)} episodes): of greedy base {b.mean() / g.mean():.4f} LR {v.mean() / g.mean():.4f}; "
          f"diff {d.mean():+.4f} ({d.mean() / g.mean():+.4f} of greedy); wins/losses {w}/{lo} (ties {len(d) - w - lo}); "
          f"paired Wilcoxon p {p:.3g}")
    print(f"never base/LR {never[0]}/{never[1]}; split base/LR {nsplit[0]}/{nsplit[1]}; live declared max base/LR "
          f"{fmax[0]}/{fmax[1]}, at the end base/LR {fend[0]}/{fend[1]}")
    print(f"LR: {steps.sum()} failure re-plan steps, {fired.sum()} fell back to the full re-solve ({fired.sum() / max(steps.sum(), 1):.1%}); "
          f"episodes with a fall-back {int((fired > 0).sum())} of {len(d)}; LR == base exactly in {int((d == 0).sum())} episodes")
    mov = sum(int(np.sum(sg[k].get("cr_movers", 0))) for k in keys)
    nonbr = sum(int(np.sum(sg[k].get("lr_nonbr", 0))) for k in keys)
    print(f"LR: movers over all composed repairs {mov} ({mov / max(steps.sum() - fired.sum(), 1):.2f} per composed step); fall-backs for want of a live neighbour {nonbr}")
    fend_ep = [np.concatenate([np.array(r[k]["false_end"]) for k in keys]) for r in (base, sg)]
    print(f"episodes with more live UAVs declared at the end under LR than base: {int((fend_ep[1] > fend_ep[0]).sum())}, fewer: {int((fend_ep[1] < fend_ep[0]).sum())}")
    for name, sel in (("base split", split), ("base not split", ~split), ("a fall-back", fired > 0)):
        x = d[sel]
        if sel.any():
            print(f"  {name}: {sel.sum()} episodes, mean diff {x.mean():+.4f} (share of pooled {x.sum() / len(d):+.4f}), "
                  f"wins/losses {(x > 0).sum()}/{(x < 0).sum()}")
    print()
