"""Session 19: the suite's own episodes of a family, split by mission (a family's mean can
hide one layout below 0.92). Runs `run_family` exactly as `plmarl suite` does (same twin
seeds, same episodes) and reports, per mission and T_up, each method's coverage and its mean
per-episode fraction of the best reference (service, greedy, clairvoyant).

usage: PYTHONPATH=. python per_mission.py SEED EPISODES METHODS TUPS FAMILY[,FAMILY] OUT.json
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from plmarl_sitl.learning.eval.evaluate import needed_policies
from plmarl_sitl.learning.eval.references import best_reference
from plmarl_sitl.learning.eval.suite import episodes_per_mission, family_tups, load_suite, run_family
from plmarl_sitl.learning.nn.io import load_policy

SUITE = Path(__file__).resolve().parents[4] / "missions" / "suite" / "suite.yaml"


def main() -> None:
    seed, episodes, methods = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3].split(",")
    tups, names, out_path = [int(t) for t in sys.argv[4].split(",")], sys.argv[5].split(","), sys.argv[6]
    spec, families = load_suite(SUITE)
    out: dict = {"seed": seed, "episodes": episodes, "methods": methods, "rows": []}
    for name in names:
        fam = families[name]
        loaded = {meth: load_policy(Path("policies") / meth, fam.missions[0]) for meth in sorted(needed_policies(methods))}
        runs = run_family(fam, loaded, methods, tups, episodes, seed)
        counts = episodes_per_mission(episodes, len(fam.missions))
        edges = np.cumsum([0, *counts])
        for tup in family_tups(fam, tups):
            for v, mission in enumerate(fam.spec.missions):
                sl = slice(edges[v], edges[v + 1])
                per = {m: (runs[(m, tup)].coverage[sl], runs[(m, tup)].trace[sl]) for m in methods}
                best = best_reference(per)
                row = {"family": name, "mission": mission, "tup": tup, "episodes": int(counts[v]),
                       "best_reference_coverage": float(best.coverage.mean()),
                       "best_reference": {r: int((best.which == r).sum()) for r in sorted(set(best.which))}}
                for m in methods:
                    c = per[m][0]
                    row[m] = {"coverage": float(c.mean()), "frac_of_best": float((c / best.coverage).mean())}
                out["rows"].append(row)
                print(name, mission, tup, {m: (round(row[m]["coverage"], 4), round(row[m]["frac_of_best"], 3)) for m in methods},
                      row["best_reference"], flush=True)
    Path(out_path).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
