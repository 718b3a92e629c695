# ruff: noqa  (a scratch probe kept to reproduce the numbers in docs/RESULTS.md, session 14; not product code)
"""Session 14 probes on TRAINING twin seed 4242 (issue 24 part 3): service against a leashed move
toward the sensed users' centroid (cenL, L = 15/30/60 m), the CTDE react teacher, the evidence bound,
greedy and clairvoyant, paired. Scratch harness kept for reproducibility:

    PYTHONPATH=. python docs/results/issue24/session14/probe_headroom.py 20 4242 2of6_a,2of6_b 15,50 react,cen15,cen30,cen60
    PYTHONPATH=. python docs/results/issue24/session14/probe_headroom.py 20 4242 2of6_a,2of6_b,paper 15 react,greedy,clairvoyant
"""
import sys
import time

import numpy as np
import torch

torch.set_num_threads(1)
from scipy import stats

from plmarl_sitl.learning.eval.controllers import ServiceController
from plmarl_sitl.learning.eval.evaluate import controller_factory, run_method
from plmarl_sitl.learning.train.teacher import ReactTargets
from plmarl_sitl.mission import load_mission


class React:
    def __init__(self, mission): self.t = ReactTargets.of(mission)
    def reset(self): self.t.reset()
    @torch.no_grad()
    def act(self, obs): return self.t.accel(obs.ego, self.t.update_true(obs))

class Centroid(ServiceController):
    def __init__(self, mission, leash=30.0, gain=1.0):
        super().__init__(mission); self.leash=leash; self.gain=gain; self.rs=float(mission.radii.sensing_m)
    @torch.no_grad()
    def act(self, obs):
        xy = self.targets.update(obs.t, obs.ego, obs.nbr_state, obs.nbr_t_rx, obs.demand, mask=obs.nbr_mask, alive=obs.alive, gossip=obs.gossip)
        cen = obs.ego[..., :2] + self.gain * self.rs * obs.sense[..., 1:3]
        d = cen - xy
        n = d.norm(dim=-1, keepdim=True).clamp(min=1e-6)
        d = d * torch.clamp(self.leash / n, max=1.0)
        has = obs.sense[..., :1] > 0
        goal = torch.where(has, xy + d, xy)
        return self.targets.accel(obs.ego, goal)


from plmarl_sitl.learning.nn.plan import ServiceTargets


class EvidenceTargets(ServiceTargets):
    """service's rule + a perfect local-evidence declaration: i declares j (truly dead) once an
    instant after j's death has passed at which i had heard j at the instant before the death."""
    def reset(self):
        super().reset(); self.death = None
    def on_failures(self, t, mask, alive, gossip, t_rx, ego, held):
        if self.death is None:
            self.death = torch.full(alive.shape, 10**9, dtype=torch.long)
        self.death = torch.where(~alive & (self.death == 10**9), torch.full_like(self.death, t), self.death)
        dead = ~alive
        b, n = alive.shape
        ev = torch.zeros(b, n, n, dtype=torch.bool)
        now_inst = self.instants.last(t)
        for e in range(b):
            for j in range(n):
                if dead[e, j]:
                    td = int(self.death[e, j])
                    # instants at or after td up to now; need one
                    if now_inst >= td or self.instants.is_instant(td):
                        if now_inst < td: continue
                        before = self.instants.last(td - 1)
                        ev[e, :, j] = t_rx[e, :, j] >= before
        ev &= alive.unsqueeze(-1) & ~gossip.failed
        if bool(ev.any()):
            at = torch.full_like(gossip.epoch, now_inst)
            gossip.declare(ev, torch.where(ev.any(-1), at, torch.zeros_like(at)))
        super().on_failures(t, mask, alive, gossip, t_rx, ego, held)

class Evidence(ServiceController):
    def __init__(self, mission):
        super().__init__(mission)
        self.targets = EvidenceTargets(mission)

fams = {"2of6_a": "missions/suite/failure_2of6_a.yaml", "2of6_b": "missions/suite/failure_2of6_b.yaml",
        "transit": "missions/suite/failure_transit.yaml", "split": "missions/suite/failure_split.yaml",
        "diffuse": "missions/suite/diffuse_failure.yaml", "paper": "missions/paper_urban.yaml"}
E = int(sys.argv[1]); seed = int(sys.argv[2]); which = sys.argv[3].split(","); tups=[int(x) for x in sys.argv[4].split(",")]
makers = {"evidence": lambda env: Evidence(env.mission), "react": lambda env: React(env.mission), "greedy": controller_factory("greedy", {}),
          "clairvoyant": controller_factory("clairvoyant", {})}
for L in (15, 30, 60):
    makers[f"cen{L}"] = (lambda leash: lambda env: Centroid(env.mission, leash))(L)
for f in which:
    fp = 1.0 if f == "diffuse" else 0.0
    for tup in tups:
        m = load_mission(fams[f]).with_tup(tup)
        base = run_method(m, lambda env: ServiceController(env.mission), E, seed, batch=E, failure_prob=fp).coverage
        line = f"{f} T{tup} service {base.mean():.4f} |"
        for name in sys.argv[5].split(","):
            t0 = time.time()
            c = run_method(m, makers[name], E, seed, batch=E, failure_prob=fp).coverage
            d = c - base
            p = stats.wilcoxon(c, base).pvalue if np.any(d != 0) else 1.0
            line += f" {name} {c.mean():.4f} d{d.mean():+.4f} w{int((d>0).sum())}/{E} pw{p:.1g} pm{stats.mannwhitneyu(c, base).pvalue:.2g} ({time.time()-t0:.0f}s) |"
        print(line, flush=True)
