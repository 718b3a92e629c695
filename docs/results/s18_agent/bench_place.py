"""Thread CPU of `SearchPlacement.place` on the demand maps of a scale_20 run (agent 0's trace).

`PYTHONPATH=TREE python3 docs/results/s18_agent/bench_place.py RUN_DIR [REPS]`: RUN_DIR is a
`swarm up` output (its mission.yaml and agents/agent0.trace.jsonl, whose lines carry each map the
agent used); prints the min and median over REPS of the mean ms per map, and a hash of the picks
(equal hashes: the same points and served users)."""

from __future__ import annotations

import hashlib
import json
import sys
import time

import numpy as np

from plmarl_sitl.learning.nn.plan import service_grid
from plmarl_sitl.mission import load_mission
from plmarl_sitl.model.placement import SearchPlacement
from plmarl_sitl.model.service import grid_counts


def main(run: str, reps: int) -> None:
    mission = load_mission(f"{run}/mission.yaml")
    grid = service_grid(mission)
    with open(f"{run}/agents/agent0.trace.jsonl") as f:
        maps = [np.array(json.loads(line)["demand"]) for line in f if '"demand"' in line]
    counts = [grid_counts(cells, grid)[None] for cells in maps]
    placer = SearchPlacement()
    for c in counts:  # warm: imports, the lattice tables
        placer.place(grid, c, mission.n_uavs)
    per_map = []
    for _ in range(reps):
        t = time.thread_time()
        out = [placer.place(grid, c, mission.n_uavs) for c in counts]
        per_map.append((time.thread_time() - t) * 1e3 / len(counts))
    digest = hashlib.sha256(b"".join(p.tobytes() + s.tobytes() for p, s in out)).hexdigest()[:12]
    print(f"{len(counts)} maps: ms per map min {min(per_map):.2f} median {sorted(per_map)[len(per_map) // 2]:.2f}; picks {digest}")


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 5)
