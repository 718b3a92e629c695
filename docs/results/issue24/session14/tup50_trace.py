"""Issue 24, T_up 50: mean coverage of the 2-of-6 families per 20-s bin from the failure, `replan` and `instant` (seed S; with a second argument: the pinned prototype at that reach).

    PYTHONPATH=. python docs/results/issue24/session14/tup50_trace.py S [REACH]
"""
import sys

from plmarl_sitl.bench import replan as bench  # noqa: E402
from plmarl_sitl.learning.train.seeds import suite_twin_seed  # noqa: E402
from plmarl_sitl.mission import load_mission  # noqa: E402

pin = len(sys.argv) > 2
if pin:
    sys.path.insert(0, 'docs/results/issue24/session14')
    import pinned_replan as P
    P.REACH = float(sys.argv[2])
    P.TeamPlans.replan = P.pinned_replan
seed = int(sys.argv[1])
for v, path in enumerate(["missions/suite/failure_2of6_a.yaml", "missions/suite/failure_2of6_b.yaml"]):
    m = load_mission(path).with_tup(50)
    for way in (["replan"] if pin else ["replan", "instant"]):
        r = bench.run(m, way, 10, suite_twin_seed(seed, v), 100, 60, 0.0)
        tr = r["trace"].mean(0)
        print(path[-6:], way, " ".join(f"{tr[s:s+20].mean():.3f}" for s in range(100, 300, 20)), f"after {r['coverage_after_mean']:.4f}", flush=True)
