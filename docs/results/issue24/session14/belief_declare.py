"""A realisable use of the local evidence (issue 24 part 3, session 14): the plan follower whose
copies also declare a teammate failed on the failure flag's own test, per teammate: it just left
N_i (missed `drop_after_missed` instants) while the agent's TRACKER still believes it within
R_comm ("predicted in range, yet silent", `model.signalling.silent_in_range`, the f of
docs/POLICY_IO.md). The tracker is the predictor under test: `policies/pl-marl/predictor.pt`
(the learnt phi) or the constant-velocity one (`dead_reckoning_tracker`), so the predictor now
decides declarations, and with them the re-plan. Twin only (a prototype: the agent's
`AgentPlan` does not run it), measured beside `service` on the same episodes.

    PYTHONPATH=. python docs/results/issue24/session14/belief_declare.py failure_transit,failure_2of6 --tup 15,50 --episodes 30 --seed 2043
    PYTHONPATH=. python docs/results/issue24/session14/belief_declare.py MISSION.yaml,... --false --tup 15,50 --episodes 20 --seed 99

With --false the arguments are mission files without failures, flown on TRAINING twin seeds
(`--seed` + batch), and it counts live teammates declared failed at the end of each episode.
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
from plmarl_sitl.learning.eval.evaluate import run_method
from plmarl_sitl.learning.eval.stats import mann_whitney_p, mean_ci95
from plmarl_sitl.learning.eval.suite import (
    BATCH,
    FAILURE_AT_S,
    episodes_per_mission,
    family_tups,
    load_suite,
    twin_seeds,
)
from plmarl_sitl.learning.nn.belief import Beliefs
from plmarl_sitl.learning.nn.io import load_policy, script
from plmarl_sitl.learning.train.predictor import dead_reckoning_tracker
from plmarl_sitl.mission import load_mission
from plmarl_sitl.twin.rollout import rollout


class BeliefDeclare(ServiceController):
    """`service`, plus: i declares j when j leaves N_i while i's tracker believes it within R_comm."""

    def __init__(self, mission, tracker) -> None:  # noqa: ANN001
        super().__init__(mission)
        self.beliefs = Beliefs(tracker)
        self.comm = float(mission.radii.comm_m)
        self.final_false = None

    def reset(self) -> None:
        super().reset()
        self.beliefs.reset()
        self.prev_mask = None

    @torch.no_grad()
    def act(self, obs) -> torch.Tensor:  # noqa: ANN001
        belief, _ = self.beliefs.catch_up(obs.t, obs.nbr_state, obs.nbr_t_rx)
        if self.prev_mask is not None and obs.gossip is not None:
            dropped = self.prev_mask & ~obs.nbr_mask & obs.alive.unsqueeze(-1)
            d = belief[..., :3] - obs.ego[..., None, :3]
            sus = dropped & ((d * d).sum(-1) <= self.comm * self.comm) & ~obs.gossip.failed
            if bool(sus.any()):
                at = torch.full_like(obs.gossip.epoch, self.targets.instants.last(obs.t))
                obs.gossip.declare(sus, torch.where(sus.any(-1), at, torch.zeros_like(at)))
        self.prev_mask = obs.nbr_mask.clone()
        out = super().act(obs)
        if obs.gossip is not None:  # live teammates some live agent counts failed (for --false)
            self.final_false = (obs.gossip.failed & obs.alive.unsqueeze(-1) & obs.alive.unsqueeze(-2)).sum((-1, -2))
        return out


def trackers() -> dict:
    phi = load_policy("policies/pl-marl").tracker
    return {"phi": phi, "cv": script(dead_reckoning_tracker(10))}


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("what")
    p.add_argument("--tup", default="15,50")
    p.add_argument("--episodes", type=int, default=30)
    p.add_argument("--seed", type=int, default=2043)
    p.add_argument("--false", action="store_true")
    a = p.parse_args()
    torch.set_num_threads(1)
    tr = trackers()
    out = []
    if a.false:
        for path in a.what.split(","):
            for tup in [int(x) for x in a.tup.split(",")]:
                m = load_mission(path).with_tup(tup)
                for name, t in tr.items():
                    holder = []

                    def make(env, t=t, holder=holder):  # noqa: ANN001, ANN202
                        c = BeliefDeclare(env.mission, t)
                        holder.append(c)
                        return c

                    rollout(m, make, a.episodes, a.seed, batch=a.episodes)
                    pairs = holder[-1].final_false
                    row = {"mission": path, "tup": tup, "tracker": name, "episodes": a.episodes, "seed": a.seed,
                           "episodes_with_false": int((pairs > 0).sum()), "false_pairs": int(pairs.sum())}
                    print(json.dumps(row), flush=True)
                    out.append(row)
        print(json.dumps(out, indent=1))
        return
    _, fams = load_suite(PROJECT_SUITE)
    for name in a.what.split(","):
        fam = fams[name]
        seeds = twin_seeds(a.seed, a.episodes, fam)
        counts = episodes_per_mission(a.episodes, len(fam.missions))
        t_fail = fam.spec.failure_at_s if fam.spec.failure_at_s is not None else FAILURE_AT_S
        makers = {"service": lambda env: ServiceController(env.mission)}
        for k, t in tr.items():
            makers[f"declare-{k}"] = (lambda trk: lambda env: BeliefDeclare(env.mission, trk))(t)
        for tup in family_tups(fam, [int(x) for x in a.tup.split(",")]):
            cov = {}
            for label, make in makers.items():
                t0 = time.time()
                runs = [run_method(m.with_tup(tup), make, e, s[0], batch=BATCH, failure_prob=fam.spec.failure_prob)
                        for m, e, s in zip(fam.missions, counts, seeds, strict=True) if e > 0]
                cov[label] = np.concatenate([r.coverage for r in runs])
                print(f"{name} T_up {tup} {label}: {cov[label].mean():.4f} ({time.time() - t0:.0f} s)", flush=True)
            row = {"family": name, "tup": tup, "episodes": a.episodes, "seed": a.seed, "failure_at_s": t_fail,
                   "coverage": {k: {"mean": mean_ci95(v)[0], "ci95": list(mean_ci95(v)[1])} for k, v in cov.items()},
                   "versus": []}
            for x, y in (("declare-phi", "service"), ("declare-cv", "service"), ("declare-phi", "declare-cv")):
                d = cov[x] - cov[y]
                row["versus"].append({"method": x, "versus": y, "difference": float(d.mean()), "wins": int((d > 0).sum()),
                                      "losses": int((d < 0).sum()), "p_mann_whitney": mann_whitney_p(cov[x], cov[y]),
                                      "p_wilcoxon": float(stats.wilcoxon(cov[x], cov[y]).pvalue) if np.any(d != 0) else 1.0})
            print(json.dumps(row["versus"]), flush=True)
            out.append(row)
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
