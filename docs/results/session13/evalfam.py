"""Coverage of greedy / service / service-local on suite missions; seed from argv. Prints one JSON line per (mission, method)."""
import json, sys, time
from plmarl_sitl.mission import load_mission
from plmarl_sitl.learning.eval.evaluate import controller_factory, run_method
seed = int(sys.argv[1]); eps = int(sys.argv[2])
for path in sys.argv[3:]:
    m = load_mission(path)
    for meth in ("service", "service-local", "greedy"):
        t0 = time.process_time()
        r = run_method(m, controller_factory(meth, {}), eps, seed, batch=eps)
        print(json.dumps({"mission": path, "method": meth, "seed": seed, "episodes": eps,
                          "coverage_from50": float(r.coverage.mean()) if hasattr(r, "coverage") else None,
                          "per_episode": [round(float(x), 4) for x in r.coverage], "cpu_s": time.process_time() - t0}), flush=True)
