# ruff: noqa  (a scratch script kept to reproduce the tables of session 21; not product code)
"""Markdown tables from held_out.py's JSON: per family and T_up, `service`, the default `pl-marl` and the
candidate `cand`: coverage, paired differences (wins/losses, paired Wilcoxon p, MWU p), lambda_2, split share,
the fraction of the best reference run (service, greedy).

    python docs/results/issue24/session21/learn/table.py docs/results/issue24/session21/learn/held_out_s2491.json
"""
import json
import sys

import numpy as np

d = json.load(open(sys.argv[1]))
print(f"Suite run seed {d['seed']}, {d['episodes']} episodes per family and T_up; candidate {d['cands']}\n")
print("| family | T_up | `service` | default `pl-marl` - service (w/l, paired p, MWU p) | candidate - service (w/l, paired p, MWU p) "
      "| candidate - default (w/l, paired p, MWU p) | lambda_2 svc / def / cand | split svc / def / cand | frac of best (svc, greedy): def / cand |")
print("|---|---|---|---|---|---|---|---|---|")


def cell(v):
    return f"{v['d_mean']:+.4f} ({v['wins']}/{v['losses']}, {v['p_paired']:.2g}, {v['p']:.2g})"


worst = []
for fam, rows in d["families"].items():
    tups = sorted({int(k.split("@")[1]) for k in rows})
    for t in tups:
        s, p, c = rows[f"service@{t}"], rows[f"pl-marl@{t}"], rows[f"cand@{t}"]
        print(f"| {fam} | {t} | {s['mean']:.4f} | {cell(p['vs_service'])} | {cell(c['vs_service'])} | {cell(c['vs_pl-marl'])} "
              f"| {s['lambda2']:.2f} / {p['lambda2']:.2f} / {c['lambda2']:.2f} | {s['split']:.3f} / {p['split']:.3f} / {c['split']:.3f} "
              f"| {p['frac_best']:.3f} / {c['frac_best']:.3f} |")
        worst.append((fam, t, p["vs_service"]["d_mean"], c["vs_service"]["d_mean"], c["vs_pl-marl"]["d_mean"], p["frac_best"], c["frac_best"]))
print()
n = len(worst)
print(f"cells {n}: default >= service in {sum(w[2] >= 0 for w in worst)}, candidate >= service in {sum(w[3] >= 0 for w in worst)}, "
      f"candidate >= default in {sum(w[4] >= 0 for w in worst)}; candidate < default by more than 0.002 in "
      f"{[(w[0], w[1], round(w[4], 4)) for w in worst if w[4] < -0.002]}; candidate < service in {[(w[0], w[1], round(w[3], 4)) for w in worst if w[3] < 0]}; "
      f"min frac of best: default {min(w[5] for w in worst):.3f}, candidate {min(w[6] for w in worst):.3f}")
