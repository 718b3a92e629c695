"""H-trace24: extra cuts of trace.py's JSON (classify.py's classes): the channel class's in-range cut pairs, the
failure's own instant, the stored `instant` way's splits, and the non-split episodes' loss by `never` (stored JSONs).

    python docs/results/issue24/session24/trace/extra.py trace_s7_14.json
"""
import json
import sys
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

from classify import greedy_of, klass, stored  # noqa: E402

rows = json.loads(Path(sys.argv[1]).read_text())["rows"]
g = greedy_of()
gmean = float(np.mean([x for v in g.values() for x in v]))
st = stored()
R_LINK = 0.95 * 350
split = [r for r in rows if r["split_instants"]]
print("channel class: the cut pairs within R_comm (d, SINR both ways):")
for r in split:
    k = klass(r)
    if k[0] != "channel":
        continue
    inr = [p for p in r["pairs"] if p["in_range"]]
    print(f"- seed {r['seed']} {r['mission']} ep {r['episode']} t {r['t']}: " + "; ".join(
        f"{p['i']}-{p['j']} {p['d']:.0f} m{' (<= R_link)' if p['d'] <= R_LINK else ''} {p['sinr_ij_db']}/{p['sinr_ji_db']} dB" for p in inr))
ds = [p["d"] for r in split if klass(r)[0] == "channel" for p in r["pairs"] if p["in_range"]]
print(f"  in-range cut pairs: {len(ds)}, d median {np.median(ds):.0f} m, min {min(ds):.0f}, <= R_link {sum(d <= R_LINK for d in ds)}")
one_way = sum(any(p["in_range"] and (p["i_hears_j"] or p["j_hears_i"]) for p in r["pairs"]) for r in split if klass(r)[0] == "channel")
print(f"  channel episodes with an in-range cut pair heard one way: {one_way}")
print("\nclass x heard graph split at 100 s (the failure's instant; the failed UAVs were relays for the old positions):")
ct = Counter((klass(r)[0], bool(r["split100"]), bool(r["pre_plan_connected"])) for r in split)
for k, v in sorted(ct.items()):
    print(f"- {k[0]}, split at 100 s {k[1]}, pre-failure plan minus the failed connected {k[2]}: {v}")
print("\nthe stored `instant` way (every survivor knows at once): split episodes, pl-marl T_up 50:")
ins = [(s, m_, sum(v["split"])) for (s, m_, w), v in st.items() if w == "instant"]
print(f"  {sum(x[2] for x in ins)} of {10 * len(ins)} episodes ({ins})")
print("\nnon-split episodes: loss by `never` (a failure some survivor never learns; stored replan rows' all_know_s):")
by = defaultdict(list)
for r in rows:
    s = st.get((r["seed"], r["mission"], "replan"))
    ak = s["all_know_s"][r["episode"]] if s and "all_know_s" in s else None
    never = ak is None or (isinstance(ak, float) and np.isnan(ak))
    cls = "split" if r["split_instants"] else "no split"
    by[(cls, "never" if never else "all know")].append(r["instant"] - r["after"])
tot = sum(r["instant"] - r["after"] for r in rows)
for k, v in sorted(by.items()):
    print(f"- {k[0]}, {k[1]}: {len(v)} episodes, loss/episode {np.mean(v) / gmean:+.4f} of greedy, share {sum(v) / tot:.1%}, "
          f"pooled {sum(v) / len(rows) / gmean:.4f}")

print("\nco-located survivors at the first split instant (two survivors flying the same point of different copies):")
from itertools import combinations  # noqa: E402
col = defaultdict(list)
for r in split:
    c = r["copies"]
    dmin, pair = min((float(np.hypot(*np.subtract(c[a]["pos"], c[b]["pos"]))), (a, b)) for a, b in combinations(c, 2))
    same_pt = c[pair[0]]["point"] == c[pair[1]]["point"]
    col[(klass(r)[0], dmin < 50)].append((r["seed"], r["mission"], r["episode"], round(dmin), same_pt, r["instant"] - r["after"]))
for k, v in sorted(col.items()):
    print(f"- {k[0]}, two survivors within 50 m {k[1]}: {len(v)}, loss/episode {np.mean([x[5] for x in v]) / gmean:+.4f}, "
          f"same point {sum(x[4] for x in v)}: {[x[:4] for x in v] if k[1] else ''}")

print("\neach copy's own plan (all survivors at the points of one copy, with the channel), over the 45 split episodes:")
full = [r for r in split if any(v["full"] for v in r["copy_plan"].values())]
print(f"- some survivor knows both failures: {len(full)}; of these a full-knowledge copy's plan is connected: "
      f"{sum(any(v['full'] and v['conn'] for v in r['copy_plan'].values()) for r in full)}")
print(f"- some copy's own plan connected: {sum(any(v['conn'] for v in r['copy_plan'].values()) for r in split)}; "
      f"every copy's own plan connected: {sum(all(v['conn'] for v in r['copy_plan'].values()) for r in split)}; "
      f"every copy's own plan split: {sum(not any(v['conn'] for v in r['copy_plan'].values()) for r in split)}")
print(f"- every copy's own plan connected by distance alone: {sum(all(v['dist_conn'] for v in r['copy_plan'].values()) for r in split)}")

print("\nwhat the survivors' copies know at the first split instant (copies of the 45 split episodes):")
kn = Counter(len(v["copy_failed"]) for r in split for v in r["copies"].values())
print(f"- copies knowing 0 / 1 / 2 failures: {dict(sorted(kn.items()))}")
print(f"- episodes where the copies' failed sets include both single failures (one survivor knows X only, another Y only): "
      f"{sum(len({tuple(v['copy_failed']) for v in r['copies'].values() if len(v['copy_failed']) == 1}) == 2 for r in split)}")
print(f"- split at >= 2 instants: {sum(len(r['split_instants']) >= 2 for r in split)}; first split at 150 s: {sum(r['t'] == 150 for r in split)}")
