"""Session 24, after the judgement (diagnosis only): how far the split gate's condition is from firing.
For every failure re-plan step that reaches the gate (SG on, margin m2), the stranded distance of the
full re-solve: the largest, over the survivors it moves, of the distance from where the mover is T_up
after the step (V_max, straight) to the nearest other survivor's old point, minus R_link (> 0: the gate
fires). Printed per episode with the episode's split (SG run) and per-step quantiles.

    PYTHONPATH=. python docs/results/issue24/session24/fail/diag_gate.py SEED MISSION TUP [CONTROLLER]
"""
import importlib.util
import sys

import numpy as np

from plmarl_sitl.learning.eval.controllers import ServiceController
from plmarl_sitl.learning.eval.evaluate import controller_factory
from plmarl_sitl.learning.nn.io import load_policy
from plmarl_sitl.learning.train.seeds import suite_twin_seed
from plmarl_sitl.mission import load_mission
from plmarl_sitl.model import service as service_mod

spec = importlib.util.spec_from_file_location("decompose", __file__.replace("diag_gate.py", "decompose.py"))
dec = importlib.util.module_from_spec(spec)
spec.loader.exec_module(dec)

seed, mission, tup = int(sys.argv[1]), sys.argv[2], int(sys.argv[3])
ctl = sys.argv[4] if len(sys.argv) > 4 else "pl-marl"
service_mod.SPLIT_GATE, service_mod.MOVERS_MARGIN_FRAC = True, 0.02
gaps: list[float] = []
_prone = service_mod.split_prone


def measured(old, new, reach_m, link_m):  # noqa: ANN001, ANN201
    step = new - old
    length = np.sqrt((step**2).sum(-1))
    at = old + step * np.minimum(1.0, reach_m / np.maximum(length, 1e-9))[:, None]
    d = np.sqrt(((at[:, None] - old[None]) ** 2).sum(-1))
    np.fill_diagonal(d, np.inf)
    moving = length > 0
    gaps.append(float((d.min(-1)[moving] - link_m).max()) if moving.any() and len(old) > 1 else float("-inf"))
    return _prone(old, new, reach_m, link_m)


service_mod.split_prone = measured
variant = 1 if mission.endswith("_b.yaml") else 0
m = load_mission(mission).with_tup(tup)
make = (lambda env: ServiceController(env.mission)) if ctl == "service" else controller_factory(ctl, {"pl-marl": load_policy("policies/pl-marl")})
per_ep: dict[int, list[float]] = {}
_fewest = service_mod.TeamPlans._fewest_movers


def tagged(self, b, a, counts, alive, src):  # noqa: ANN001, ANN202
    before = len(gaps)
    out = _fewest(self, b, a, counts, alive, src)
    per_ep.setdefault(b, []).extend(gaps[before:])
    return out


service_mod.TeamPlans._fewest_movers = tagged
r = dec.run(m, make, 10, suite_twin_seed(seed, variant), "replan")
for b in range(10):
    g = np.array(per_ep.get(b, []))
    print(f"episode {b}: split {r['split'][b]} steps {len(g)} fired {int((g > 0).sum())} "
          f"largest stranded distance - R_link {g.max() if len(g) else float('nan'):+.0f} m")
g = np.array([x for x in gaps if np.isfinite(x)])
print(f"{len(gaps)} steps; stranded distance - R_link quantiles 10/50/90/max: "
      f"{np.quantile(g, 0.1):+.0f} {np.quantile(g, 0.5):+.0f} {np.quantile(g, 0.9):+.0f} {g.max():+.0f} m")
