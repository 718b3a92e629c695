"""Thread CPU of one visit's cover bookkeeping in `LocalSearch.improve` (`_LatticeCover.without` then `add`, the point
kept), base (a94367a's window slicing, copied below) vs the tree's kept views, on the first plan of a scale_20 run's first
map, every point in turn; alternated, median and min over rounds of ns per visit, and whether both give the same gains.
`PYTHONPATH=TREE python3 docs/results/s23_agent/ab_visit.py RUN_DIR [ROUNDS]`."""
import json
import sys
import time

import numpy as np

import plmarl_sitl.model.placement as P
from plmarl_sitl.learning.nn.plan import service_grid
from plmarl_sitl.mission import load_mission
from plmarl_sitl.model.service import grid_counts

MOVE = P.MOVE


def without_base(cover, p, inside):
    f = cover.frame
    i, j = divmod(p, f.ne)
    rs, cs = slice(i + f.k0, i + f.k0 + f.hk), slice(j + f.l0, j + f.l0 + f.hl)
    cnt = cover.cnt[rs, cs]
    cnt[MOVE:f.hk - MOVE, MOVE:f.hl - MOVE] -= f.stencil
    got = (cover.w[rs, cs] * (cnt == 0)).ravel() @ f.share
    return float(got[-1]), got[:-1][inside]


def add_base(cover, p):
    f = cover.frame
    i, j = divmod(p, f.ne)
    rs, cs = slice(i + f.k0, i + f.k0 + f.hk), slice(j + f.l0, j + f.l0 + f.hl)
    cover.cnt[rs, cs][MOVE:f.hk - MOVE, MOVE:f.hl - MOVE] += f.stencil


run = sys.argv[1]
rounds = int(sys.argv[2]) if len(sys.argv) > 2 else 15
mission = load_mission(f"{run}/mission.yaml")
grid = service_grid(mission)
with open(f"{run}/agents/agent0.trace.jsonl") as f:
    cells = next(np.array(json.loads(line)["demand"]) for line in f if '"demand"' in line)
row = grid_counts(cells, grid).astype(np.float64)
w = grid.sub_weights(row)
picks = grid.greedy_one(w, grid.map_gains(row), mission.n_uavs)
local = P.LocalSearch(grid)
cover = P._LatticeCover(local, w, local.counts(picks))
visits = [(int(p), local.moves_of(int(p))[0]) for p in picks] * 50
same = True
for p, m in visits[:20]:  # each way leaves the counts as it found them (the point kept)
    lose_b, gains_b = without_base(cover, p, m)
    add_base(cover, p)
    lose_n, gains_n = cover.without(p, m)
    cover.add(p)
    same &= lose_b == lose_n and np.array_equal(gains_b, gains_n)
ways = {"base": (lambda p, m: without_base(cover, p, m), lambda p: add_base(cover, p)),
        "new": (cover.without, cover.add)}
ns = {k: [] for k in ways}
for r in range(rounds):
    for name in (["base", "new"] if r % 2 == 0 else ["new", "base"]):
        without, add = ways[name]
        t = time.thread_time_ns()
        for p, m in visits:
            without(p, m)
            add(p)
        ns[name].append((time.thread_time_ns() - t) / len(visits))
for name, v in ns.items():
    v = sorted(v[1:])
    print(f"{name}: ns per visit min {v[0]:.0f} median {v[len(v) // 2]:.0f}")
print("same gains:", same)
