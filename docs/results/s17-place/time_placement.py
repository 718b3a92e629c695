"""CPU time of one new map's placement on `bench infer`'s inputs (docs/RESULTS.md, session 17).

usage: PYTHONPATH=TREE OPENBLAS_NUM_THREADS=1 python time_placement.py N AREA_M search|greedy [CALLS]
"""

import sys
import time

import numpy as np

from plmarl_sitl.bench.infer import plan_inputs
from plmarl_sitl.model.placement import SearchPlacement
from plmarl_sitl.model.service import ServiceGrid, grid_counts, plan_geometry

n, area, mode = int(sys.argv[1]), float(sys.argv[2]), sys.argv[3]
calls = int(sys.argv[4]) if len(sys.argv) > 4 else 50
pi = plan_inputs(n, 0, area)  # seed 0
grid = ServiceGrid(*plan_geometry(pi.mission))
counts = np.stack([grid_counts(np.asarray(m, dtype=np.float64), grid) for m in pi.maps])
search = SearchPlacement()
place = (lambda c: grid.greedy_place(c[None], n)) if mode == "greedy" else (lambda c: search.place(grid, c[None], n))
for c in counts:  # warm-up
    place(c)
t = time.process_time()
for i in range(calls):
    place(counts[i % 2])
print(mode, n, area, "ms", round((time.process_time() - t) / calls * 1e3, 3))
