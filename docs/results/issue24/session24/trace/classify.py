"""Class each split episode of trace.py's JSON by what splits the heard graph at its first split instant,
and the coverage loss (`instant` - `replan`, mean C(t) from 130 s) per class.

    python docs/results/issue24/session24/trace/classify.py trace_s7_14.json [--detail] > classes.md

Classes, tested in this order at the first post-failure signalling instant whose heard graph (i hears j at
the instant, the env's own receive mask) is not strongly connected:
  channel      the graph with distance alone (d <= R_comm) at the true positions is connected: SINR cuts it.
  off-point    out of range, but at each survivor's own plan point (its policy's target input) the graph
               would be connected: survivors are not where their plans say. Sub: transit (a survivor on a
               cut pair is >= 30 m from its point and flying >= 5 m/s) or settled.
  copies       the graph at the points is split and the survivors' copies differ (failed set or epoch):
               sub: false (a live UAV declared in some copy), unaware (a copy lacks a true failure), epoch.
  relay        the copies agree on the true failed set, the graph at the points is split, and the
               pre-failure plan minus the failed UAVs was already split (the failed UAVs were the relays).
  re-solve     the copies agree on the truth, the graph at the points is split, the old plan minus the
               failed was not: the common re-solve itself puts the points out of reach.
"""
from __future__ import annotations

import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
FAIL = HERE.parent / "fail"


def greedy_of() -> dict:
    """(seed, mission) -> greedy per episode, from the session JSONs (greedy rows)."""
    out = {}
    for f in [FAIL / "base_s7_8.json", FAIL / "base_s11_14.json", HERE.parent.parent / "session22/fail/base_s9_10.json"]:
        for r in json.loads(f.read_text())["rows"]:
            if r["controller"] == "greedy" and r["tup"] == 50:
                out[(r["seed"], r["mission"][-6])] = r["after"]
    return out


def stored() -> dict:
    """(seed, mission, way) -> pl-marl per episode, T_up 50, from the session JSONs."""
    out = {}
    for f in [FAIL / "base_s7_8.json", FAIL / "base_s11_14.json", HERE.parent.parent / "session22/fail/base_s9_10.json"]:
        for r in json.loads(f.read_text())["rows"]:
            if r["controller"] == "pl-marl" and r["tup"] == 50:
                out[(r["seed"], r["mission"][-6], r["way"])] = r
    return out


def klass(r: dict) -> tuple[str, str]:
    if r["dist_only_connected"]:
        return "channel", "copies differ" if r["n_failed_sets"] > 1 or not r["copies_agree"] else "copies agree"
    if r["at_points_connected"]:
        cut = {p["i"] for p in r["pairs"]} | {p["j"] for p in r["pairs"]}
        moving = any(r["copies"][str(i)]["off_point"] >= 30 and r["copies"][str(i)]["speed"] >= 5 for i in cut)
        return "off-point", "transit" if moving else "settled"
    if not (r["copies_agree"] and r["copies_correct"]):
        if r["false_decl"]:
            return "copies", "false declaration"
        full = [v for v in r["copy_plan"].values() if v["full"]]
        if any(v["conn"] for v in full):
            return "copies", "a full-knowledge copy's plan is connected"
        if full:
            return "copies", "full-knowledge copies' plans split too"
        if any(v["conn"] for v in r["copy_plan"].values()):
            return "copies", "no full copy; some copy's own plan connected"
        return "copies", "no full copy; every copy's own plan split"
    return ("relay", "") if not r["pre_plan_connected"] else ("re-solve", "")


def main() -> int:
    rows = json.loads(Path(sys.argv[1]).read_text())["rows"]
    detail = "--detail" in sys.argv
    g = greedy_of()
    st = stored()
    gmean = float(np.mean([x for v in g.values() for x in v]))
    # cross-check against the stored JSONs
    dif_r, dif_i, n_i = [], [], 0
    for r in rows:
        s = st.get((r["seed"], r["mission"], "replan"))
        if s:
            dif_r.append(abs(s["after"][r["episode"]] - r["after"]))
        s = st.get((r["seed"], r["mission"], "instant"))
        if s and r["instant"] is not None:
            dif_i.append(abs(s["after"][r["episode"]] - r["instant"]))
    loss = {id(r): r["instant"] - r["after"] for r in rows}
    tot = sum(loss.values())
    split = [r for r in rows if r["split_instants"]]
    print(f"episodes {len(rows)}; greedy mean {gmean:.4f}; replan {np.mean([r['after'] for r in rows]) / gmean:.4f} of greedy, "
          f"instant {np.mean([r['instant'] for r in rows]) / gmean:.4f}")
    print(f"cross-check vs stored JSONs: replan max |diff| {max(dif_r):.2e} over {len(dif_r)} episodes; "
          f"instant max |diff| {max(dif_i) if dif_i else float('nan'):.2e} over {len(dif_i)}")
    print(f"split episodes (exact instants) {len(split)}; decompose.py's flag {sum(r['split_dec'] for r in rows)}; "
          f"both {sum(bool(r['split_instants']) and r['split_dec'] for r in rows)}")
    print(f"total loss instant - replan: {tot / len(rows):.4f} per episode ({tot / len(rows) / gmean:.4f} of greedy); "
          f"split episodes {sum(loss[id(r)] for r in split) / len(rows) / gmean:.4f} of greedy, pooled over {len(rows)}\n")
    by = defaultdict(list)
    for r in split:
        by[klass(r)].append(r)
    print("| class | sub | episodes | loss / episode (of greedy) | share of all 160 episodes' loss | of greedy, pooled over 160 | first split at 300 s only | split at >= 2 instants |")
    print("|---|---|---|---|---|---|---|---|")
    for k in sorted(by, key=lambda k: -sum(loss[id(r)] for r in by[k])):
        v = by[k]
        ls = sum(loss[id(r)] for r in v)
        print(f"| {k[0]} | {k[1]} | {len(v)} | {ls / len(v) / gmean:+.4f} | {ls / tot:.1%} | {ls / len(rows) / gmean:.4f} | "
              f"{sum(r['split_instants'] == [300] for r in v)} | {sum(len(r['split_instants']) >= 2 for r in v)} |")
    rest = [r for r in rows if not r["split_instants"]]
    lr = sum(loss[id(r)] for r in rest)
    print(f"| no split | | {len(rest)} | {lr / len(rest) / gmean:+.4f} | {lr / tot:.1%} | {lr / len(rows) / gmean:.4f} | | |")
    # flags across all split episodes
    print("\nflags over the split episodes:")
    for f in ["dist_only_connected", "at_points_connected", "at_points_dist_connected", "at_own_plan_connected",
              "pre_plan_connected", "pre_plan_dist_connected", "copies_agree", "copies_correct", "false_decl"]:
        print(f"- {f}: {sum(bool(r[f]) for r in split)} / {len(split)}")
    print(f"- some survivor unaware of a true failure: {sum(bool(r['unaware']) for r in split)} / {len(split)}")
    ts = defaultdict(int)
    for r in split:
        ts[r["t"]] += 1
    print(f"- first split instant: {dict(sorted(ts.items()))}")
    print(f"- heard graph split at the failure's own instant (100 s): {sum(bool(r['split100']) for r in split)} / {len(split)} "
          f"(all 160: {sum(bool(r['split100']) for r in rows)})")
    nfs = defaultdict(int)
    for r in split:
        nfs[r["n_failed_sets"]] += 1
    print(f"- distinct failed sets among the survivors' copies at the first split instant: {dict(sorted(nfs.items()))}")
    print(f"- survivors knowing both failures at the first split instant: "
          f"{dict(sorted(__import__('collections').Counter(sum(v['full'] for v in r['copy_plan'].values()) for r in split).items()))}")
    print(f"- max distance of a survivor from its own point at the first split instant: "
          f"median {np.median([max(c['off_point'] for c in r['copies'].values()) for r in split]):.1f} m, "
          f"max {max(max(c['off_point'] for c in r['copies'].values()) for r in split):.1f} m")
    ep = [r["copies"][k]["copy_epoch"] for r in split for k in r["copies"]]
    print(f"- copy epochs at the first split instant (survivor copies): {dict(sorted(__import__('collections').Counter(ep).items()))}")
    print(f"- a cut pair within R_comm (SINR-blocked): {sum(any(p['in_range'] for p in r['pairs']) for r in split)} / {len(split)}")
    if detail:
        print("\nper split episode:")
        for r in split:
            k = klass(r)
            print(f"\n### seed {r['seed']} {r['mission']} ep {r['episode']}: {k[0]} {k[1]}; loss {loss[id(r)] / gmean:+.4f}; "
                  f"split at {r['split_instants']}; dead {r['dead']}; components {r['components']}")
            print(f"  cut pairs: " + "; ".join(f"{p['i']}-{p['j']} d {p['d']} (points {p['d_points']}) sinr {p['sinr_ij_db']}/{p['sinr_ji_db']} dB" for p in r["pairs"]))
            for i, c in r["copies"].items():
                print(f"  {i}: pos {c['pos']} speed {c['speed']} point {c['point']} off {c['off_point']} (plan {c['off_plan']}) "
                      f"copy failed {c['copy_failed']} epoch {c['copy_epoch']} knows {c['knows']} spread {r['plan_spread'][i]} "
                      f"own-copy plan connected {r['copy_plan'][i]['conn']} (distance {r['copy_plan'][i]['dist_conn']})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
