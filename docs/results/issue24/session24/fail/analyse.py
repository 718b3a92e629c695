"""Tables of session 21's decomposition (decompose.py JSON): per controller, the fraction of
the greedy Oracle from 30 s after the failure per way, and where `instant - replan` goes.

    python docs/results/issue24/session21/fail/analyse.py decompose_s7_8.json [more.json ...]
"""
from __future__ import annotations

import json
import sys
from collections import defaultdict

import numpy as np


def load(paths: list[str]) -> dict:
    runs: dict = {}
    for p in paths:
        for r in json.load(open(p))["rows"]:
            runs[(r["controller"], r["way"], r["seed"], r["mission"].split("/")[-1])] = r
    return runs


def main() -> None:
    runs = load(sys.argv[1:])
    cells = sorted({(s, m) for (_, _, s, m) in runs})
    ctls = sorted({c for (c, _, _, _) in runs if c != "greedy"})
    ways = ["replan", "spread", "instant", "phased"]
    print("| controller | seed, mission | greedy | " + " | ".join(f"{w} (of greedy)" for w in ways if any(k[1] == w for k in runs)) + " |")
    print("|---|---|---|" + "---|" * sum(any(k[1] == w for k in runs) for w in ways))
    pooled = defaultdict(list)
    for c in ctls:
        for s, m in cells:
            g = np.array(runs[("greedy", "-", s, m)]["after"])
            row = [f"{c}", f"{s}, {m}", f"{g.mean():.4f}"]
            for w in ways:
                if ("x", w) and any(k[1] == w for k in runs):
                    r = runs.get((c, w, s, m))
                    if r is None:
                        row.append("")
                        continue
                    x = np.array(r["after"])
                    never = int(np.isnan(np.array(r["all_know_s"], dtype=float)).sum())
                    row.append(f"{x.mean():.4f} ({x.mean() / g.mean():.3f}; never {never}, split {sum(r['split'])}, false {sum(r['false_max'])}/{sum(r['false_end'])})")
                    pooled[(c, w)].append(x)
            pooled[(c, "greedy")].append(g)
            print("| " + " | ".join(row) + " |")
    print()
    print("Pooled over the cells (episodes paired):")
    print("| controller | episodes | greedy | replan | spread | instant | I - R | I - S (detection) | S - R (spreading) | of S - R: episodes whose heard graph split | of S - R: the others | I - R in episodes where some failure is never known by all |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for c in ctls:
        g = np.concatenate(pooled[(c, "greedy")])
        if not pooled.get((c, "replan")) or not pooled.get((c, "instant")):
            continue
        R = np.concatenate(pooled[(c, "replan")])
        Ins = np.concatenate(pooled[(c, "instant")])
        S = np.concatenate(pooled[(c, "spread")]) if pooled.get((c, "spread")) else np.full_like(R, np.nan)
        never = np.concatenate([np.isnan(np.array(runs[(c, "replan", s, m)]["all_know_s"], dtype=float)) for s, m in cells])
        G = g.mean()
        loss = (Ins - R) / G
        split = np.concatenate([np.array(runs[(c, "replan", s, m)]["split"]) for s, m in cells])
        sp = (S - R) / G
        print(f"| {c} | {len(R)} | {G:.4f} | {R.mean() / G:.3f} | {S.mean() / G:.3f} | {Ins.mean() / G:.3f} | {loss.mean():+.3f} | "
              f"{(Ins - S).mean() / G:+.3f} | {sp.mean():+.3f} | {sp[split].sum() / len(sp):+.3f} ({split.sum()} ep.) | "
              f"{sp[~split].sum() / len(sp):+.3f} ({(~split).sum()} ep.) | {loss[never].sum() / len(loss):+.3f} ({never.sum()} ep.) |")
    print()
    print("Flight after an instant re-plan (instant's mean trace, 130-160 s against 160-300 s):")
    for c in ctls:
        for s, m in cells:
            r = runs.get((c, "instant", s, m))
            if r:
                tr = np.array(r["trace_mean"])
                print(f"  {c} {s} {m}: 100-130 {tr[100:130].mean():.4f} 130-160 {tr[130:160].mean():.4f} 160-300 {tr[160:300].mean():.4f}")


if __name__ == "__main__":
    main()
