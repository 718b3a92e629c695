# ruff: noqa  (a scratch probe kept to reproduce the numbers in docs/RESULTS.md, session 14; not product code)
"""Session 14 probe (training twin seed 4242): service fed a map of the true users at every decision
instead of the published 30 s map.

    PYTHONPATH=. python docs/results/issue24/session14/fresh_map.py 2of6_a,paper
"""
import sys

import torch

torch.set_num_threads(1)
from scipy import stats

from plmarl_sitl.learning.eval.controllers import ServiceController
from plmarl_sitl.learning.eval.evaluate import run_method
from plmarl_sitl.mission import load_mission
from plmarl_sitl.model.demand import cell_centres, demand_cells, demand_map


class Fresh(ServiceController):
    def __init__(self, env):
        super().__init__(env.mission); self.env = env
        self.targets.period = int(env.mission.timing.decision_every_s)
        m = env.mission
        self.cent = cell_centres(m.area.north_m, m.area.east_m, m.demand.cell_m, torch.float64)
    @torch.no_grad()
    def act(self, obs):
        m = self.env.mission
        counts = demand_map(self.env.users.xy.double(), m.area.north_m, m.area.east_m, m.demand.cell_m)
        dem = demand_cells(counts, self.cent)
        xy = self.targets.update(obs.t, obs.ego, obs.nbr_state, obs.nbr_t_rx, dem.to(obs.demand.dtype), mask=obs.nbr_mask, alive=obs.alive, gossip=obs.gossip)
        return self.targets.accel(obs.ego, xy)

fams = {"2of6_a": "missions/suite/failure_2of6_a.yaml", "2of6_b": "missions/suite/failure_2of6_b.yaml", "paper": "missions/paper_urban.yaml"}
E = 20; seed = 4242
for f in sys.argv[1].split(","):
    m = load_mission(fams[f]).with_tup(15)
    base = run_method(m, lambda env: ServiceController(env.mission), E, seed, batch=E).coverage
    c = run_method(m, lambda env: Fresh(env), E, seed, batch=E).coverage
    d = c - base
    print(f, f"service {base.mean():.4f} fresh-map {c.mean():.4f} d{d.mean():+.4f} w{(d>0).sum()}/{E} pW {stats.wilcoxon(c, base).pvalue:.2g}", flush=True)
