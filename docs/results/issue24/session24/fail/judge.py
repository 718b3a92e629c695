"""Session 24: the split gate (SG) against the base, paired on the same episodes (decompose.py JSON).

    python docs/results/issue24/session24/fail/judge.py BASE.json SG.json [WAY]

Per controller: of-greedy fractions (base, SG; ratio of the means over the same episodes), the pooled
paired difference, wins/losses (identical episodes are ties, neither), paired Wilcoxon p, `never` and
`split` counts, live UAVs declared at the end, the gate's firing rate (split-prone re-plan steps of
all copies' failure re-plan steps), per cell, split against other episodes (the base's split), and
whether SG equals the base exactly in the episodes where the gate never fired.
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
    print("| cell | base of greedy | SG of greedy | diff | wins/losses | gate fired / steps | split base -> SG |")
    print("|---|---|---|---|---|---|---|")
    cols = {n: [] for n in ("b", "v", "g", "split", "fired", "steps")}
    for k in keys:
        b, v = np.array(base[k]["after"]), np.array(sg[k]["after"])
        g = np.array(base[("greedy",) + k[1:]]["after"])
        d = v - b
        fired, steps = np.array(sg[k]["gate_fired"]), np.array(sg[k]["gate_steps"])
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
    print(f"\npooled ({len(d)} episodes): of greedy base {b.mean() / g.mean():.4f} SG {v.mean() / g.mean():.4f}; "
          f"diff {d.mean():+.4f} ({d.mean() / g.mean():+.4f} of greedy); wins/losses {w}/{lo} (ties {len(d) - w - lo}); "
          f"paired Wilcoxon p {p:.3g}")
    print(f"never base/SG {never[0]}/{never[1]}; split base/SG {nsplit[0]}/{nsplit[1]}; live declared max base/SG "
          f"{fmax[0]}/{fmax[1]}, at the end base/SG {fend[0]}/{fend[1]}")
    print(f"gate: fired on {fired.sum()} of {steps.sum()} failure re-plan steps ({fired.sum() / max(steps.sum(), 1):.1%}); "
          f"episodes with a firing {int((fired > 0).sum())} of {len(d)}")
    calm = fired == 0
    print(f"episodes where the gate never fired: {calm.sum()}; SG == base exactly in {int((d[calm] == 0).sum())} of them")
    print(f"base split episodes {int(split.sum())}, of which the gate fired in {int((split & ~calm).sum())}; "
          f"the gate fired in {int((~split & ~calm).sum())} episodes that did not split")
    for name, sel in (("base split", split), ("base not split", ~split), ("gate fired", ~calm)):
        x = d[sel]
        if sel.any():
            print(f"  {name}: {sel.sum()} episodes, mean diff {x.mean():+.4f} (share of pooled {x.sum() / len(d):+.4f}), "
                  f"wins/losses {(x > 0).sum()}/{(x < 0).sum()}")
    print()
