"""What any policy that sees only its own observations could gain over `service` after a failure
(issue 24 part 3, session 14): three controllers on the suite's episodes, paired.

* `service`: the plan follower; it learns of a failure from its declaration rule
  (model/gossip.py: a teammate silent at a signalling instant where the plan-aware prediction
  put it in clear hearing or on a steady link) and from gossip at later instants.
* `evidence` (a bound, CTDE: it reads the twin's truth): `service`, plus every survivor declares
  a truly dead teammate at the first signalling instant after the death at which it misses a
  teammate it HAD heard at the instant before the death. That is the most a survivor's own
  observations can tell it (it hears nothing between instants, and its sensing shows its own
  users only), declared with no false alarm ever; gossip then carries it as for `service`.
  No policy that sees only its beliefs, its mask, f, its sensing and its plan point can know a
  failure earlier, however it is trained.
* `spread` (a bound, not a policy): `service`'s own declarations, known to every survivor the
  decision the first one declares (an event-triggered message or a zero-latency relay): what
  faster spreading of knowledge, not better detection, would buy.
* `react`: the CTDE teacher of `plmarl train --teacher react` (learning/train/teacher.py): every
  survivor knows the true failed set the second it happens and re-plans from true positions.
  What a policy with the twin's truth would gain.

Optionally the shipped learnt policy (`--policies DIR`: its `pl-marl` as the suite flies it, and
on failure_transit also its constant-velocity ablation `dead-reckoning`).

    PYTHONPATH=. python docs/results/issue24/session14/info_bound.py failure_2of6,failure_transit,failure_split,diffuse_failure \
        --tup 15,50 --episodes 30 --seed 2041 --policies policies > out.json

Coverage = mean C(t) for t > 50 s (the suite's), and `after` = mean C(t) from 30 s after the
failure to the end. p: two-sided Mann-Whitney U (as `plmarl suite`) and the paired Wilcoxon
signed-rank test (same episodes for every controller).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import torch
from scipy import stats

from plmarl_sitl.config import PROJECT_SUITE
from plmarl_sitl.learning.eval.controllers import ServiceController
from plmarl_sitl.learning.eval.evaluate import controller_factory, run_method
from plmarl_sitl.learning.eval.stats import mann_whitney_p, mean_ci95
from plmarl_sitl.learning.eval.suite import (
    BATCH,
    FAILURE_AT_S,
    episodes_per_mission,
    family_tups,
    load_suite,
    twin_seeds,
)
from plmarl_sitl.learning.nn.io import load_policy
from plmarl_sitl.learning.nn.plan import ServiceTargets
from plmarl_sitl.learning.train.teacher import ReactTargets

NEVER = 10**9


class EvidenceTargets(ServiceTargets):
    """`service`'s declarations plus a perfect local-evidence one (see the module doc)."""

    def reset(self) -> None:
        super().reset()
        self.death: torch.Tensor | None = None

    def on_failures(self, t, mask, alive, gossip, t_rx, ego, held) -> None:  # noqa: ANN001 - as ServiceTargets
        if self.death is None:
            self.death = torch.full(alive.shape, NEVER, dtype=torch.long)
        self.death = torch.where(~alive & (self.death == NEVER), torch.full_like(self.death, t), self.death)
        now = self.instants.last(t)
        ev = torch.zeros(t_rx.shape, dtype=torch.bool)
        for e, j in zip(*torch.nonzero(~alive, as_tuple=True), strict=True):
            td = int(self.death[e, j])
            if now >= td:  # an instant at or after the death has passed: j missed it
                ev[e, :, j] = t_rx[e, :, j] >= self.instants.last(td - 1)  # ... and i had heard j at the one before
        ev &= alive.unsqueeze(-1) & ~gossip.failed
        if bool(ev.any()):
            at = torch.full_like(gossip.epoch, now)
            gossip.declare(ev, torch.where(ev.any(-1), at, torch.zeros_like(at)))
        super().on_failures(t, mask, alive, gossip, t_rx, ego, held)


class EvidenceController(ServiceController):
    def __init__(self, mission) -> None:  # noqa: ANN001
        super().__init__(mission)
        self.targets = EvidenceTargets(mission)


class SpreadTargets(ServiceTargets):
    """`service`'s own declarations, but known to every survivor the decision the first one
    declares (what an event-triggered message or any zero-latency relay would buy)."""

    def on_failures(self, t, mask, alive, gossip, t_rx, ego, held) -> None:  # noqa: ANN001 - as ServiceTargets
        super().on_failures(t, mask, alive, gossip, t_rx, ego, held)
        live = alive.unsqueeze(-1)
        known = (gossip.failed & live).any(1, keepdim=True) & live  # (B, N, N): what any survivor knows
        if bool((known & ~gossip.failed).any()):
            epoch = torch.where(alive, gossip.epoch, torch.zeros_like(gossip.epoch)).amax(-1, keepdim=True)
            gossip.declare(known, torch.where(alive, epoch.expand_as(gossip.epoch), torch.zeros_like(gossip.epoch)))
            super().on_failures(t, mask, alive, gossip, t_rx, ego, held)  # re-plan the copies that just learnt


class SpreadController(ServiceController):
    def __init__(self, mission) -> None:  # noqa: ANN001
        super().__init__(mission)
        self.targets = SpreadTargets(mission)


class ReactController:
    def __init__(self, mission) -> None:  # noqa: ANN001
        self.targets = ReactTargets.of(mission)

    def reset(self) -> None:
        self.targets.reset()

    @torch.no_grad()
    def act(self, obs) -> torch.Tensor:  # noqa: ANN001
        return self.targets.accel(obs.ego, self.targets.update_true(obs))


def summary(x: np.ndarray) -> dict:
    m, (lo, hi) = mean_ci95(x)
    return {"mean": m, "ci95": [lo, hi]}


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("families")
    p.add_argument("--tup", default="15,50")
    p.add_argument("--episodes", type=int, default=30)
    p.add_argument("--seed", type=int, default=2041)
    p.add_argument("--policies", default=None, help="a policies/ directory: also fly its pl-marl (and dead-reckoning on transit)")
    a = p.parse_args()
    torch.set_num_threads(1)
    print(f"seed {a.seed} episodes {a.episodes}", flush=True)
    _, fams = load_suite(PROJECT_SUITE)
    out = []
    for name in a.families.split(","):
        fam = fams[name]
        seeds = twin_seeds(a.seed, a.episodes, fam)
        counts = episodes_per_mission(a.episodes, len(fam.missions))
        t_fail = fam.spec.failure_at_s if fam.spec.failure_at_s is not None else FAILURE_AT_S
        makers = {"service": lambda env: ServiceController(env.mission),
                  "evidence": lambda env: EvidenceController(env.mission),
                  "spread": lambda env: SpreadController(env.mission),
                  "react": lambda env: ReactController(env.mission)}
        if a.policies:
            loaded = {"pl-marl": load_policy(f"{a.policies}/pl-marl")}
            makers["pl-marl"] = controller_factory("pl-marl", loaded)
            if name == "failure_transit":
                makers["dead-reckoning"] = controller_factory("dead-reckoning", loaded)
        for tup in family_tups(fam, [int(x) for x in a.tup.split(",")]):
            cov, after = {}, {}
            for label, make in makers.items():
                t0 = time.time()
                runs = [run_method(m.with_tup(tup), make, e, s[0], batch=BATCH, failure_prob=fam.spec.failure_prob)
                        for m, e, s in zip(fam.missions, counts, seeds, strict=True) if e > 0]
                cov[label] = np.concatenate([r.coverage for r in runs])
                after[label] = np.concatenate([r.trace[:, int(t_fail) + 30:].mean(-1) for r in runs])
                print(f"{name} T_up {tup} {label}: {cov[label].mean():.4f} after {after[label].mean():.4f} "
                      f"({time.time() - t0:.0f} s)", flush=True)
            row = {"family": name, "tup": tup, "episodes": a.episodes, "seed": a.seed, "failure_at_s": t_fail,
                   "coverage": {k: summary(v) for k, v in cov.items()},
                   "after_failure_30s": {k: summary(v) for k, v in after.items()}, "versus": []}
            pairs = [(k, "service") for k in cov if k != "service"]
            if "dead-reckoning" in cov:
                pairs.append(("pl-marl", "dead-reckoning"))
            for x, y in pairs:
                d = cov[x] - cov[y]
                row["versus"].append({
                    "method": x, "versus": y, "difference": summary(d), "wins": int((d > 0).sum()), "losses": int((d < 0).sum()),
                    "p_mann_whitney": mann_whitney_p(cov[x], cov[y]),
                    "p_wilcoxon": float(stats.wilcoxon(cov[x], cov[y]).pvalue) if np.any(d != 0) else 1.0})
            out.append(row)
            print(json.dumps(row["versus"]), flush=True)
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
