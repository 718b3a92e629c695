"""In-process A/B of `SearchPlacement.place` on the demand maps of a scale_20 run (agent 0's trace): the base's
model/placement.py (loaded from BASE_TREE under another module name; it imports the rest from the tree on PYTHONPATH)
against the tree's, alternated round by round; thread CPU per map, min and median over the rounds (the first dropped),
and a hash of the picks and served users of each (equal: the same placements).
`PYTHONPATH=TREE python3 docs/results/s23_agent/ab_place.py RUN_DIR BASE_TREE [ROUNDS]`."""
import hashlib
import importlib.util
import json
import sys
import time

import numpy as np

import plmarl_sitl.model.placement as new
from plmarl_sitl.learning.nn.plan import service_grid
from plmarl_sitl.mission import load_mission
from plmarl_sitl.model.service import grid_counts

run, base_tree = sys.argv[1], sys.argv[2]
rounds = int(sys.argv[3]) if len(sys.argv) > 3 else 15
spec = importlib.util.spec_from_file_location("base_placement", f"{base_tree}/plmarl_sitl/model/placement.py")
base = importlib.util.module_from_spec(spec)
spec.loader.exec_module(base)
mission = load_mission(f"{run}/mission.yaml")
grid = service_grid(mission)
with open(f"{run}/agents/agent0.trace.jsonl") as f:
    maps = [np.array(json.loads(line)["demand"]) for line in f if '"demand"' in line]
counts = [grid_counts(c, grid)[None] for c in maps]
placers = {"base": base.SearchPlacement(), "new": new.SearchPlacement()}
per_map = {k: [] for k in placers}
digest = {}
for r in range(rounds):
    for name in (["base", "new"] if r % 2 == 0 else ["new", "base"]):
        t = time.thread_time()
        out = [placers[name].place(grid, c, mission.n_uavs) for c in counts]
        per_map[name].append((time.thread_time() - t) * 1e3 / len(counts))
        digest[name] = hashlib.sha256(b"".join(p.tobytes() + s.tobytes() for p, s in out)).hexdigest()[:12]
for name, v in per_map.items():
    v = sorted(v[1:])
    print(f"{name}: {len(counts)} maps, ms per map min {v[0]:.2f} median {v[len(v) // 2]:.2f}; picks {digest[name]}")
