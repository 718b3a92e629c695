# ruff: noqa  (a scratch probe kept to reproduce the numbers of session 20; not product code)
"""Session 20 probe (training twin seeds only): the tracking teachers as controllers, and learnt
policies from a directory, paired with `service` on the same episodes.

    PYTHONPATH=. python docs/results/issue24/session20/learn/probe.py --missions probe_paper,probe_paper_vfast,probe_random \
        --methods service,service-track,teach-true-r1.5-m30,pol:runs/move1 --episodes 20 --seed 5001 --tup 15

Methods beyond `plmarl eval`'s:
* teach-<sensed|true>-r<k>-m<L>[-u]: the plan follower flying the imitation teacher's point
  (learning/train/teacher.py::track_target): the plan point moved toward the centroid of the users
  within k R_s (sensed: the UAV's own sensing, k = 1; true: the twin's true users, privileged), by at
  most L m, within the plan's link and spacing slack (-u: without);
* teach-<jsensed|jtrue>-r<k>-m<L>: the centralised teacher (teacher.py::joint_track): each point
  shifted as far as the team's true chosen points stay linked and spaced; -l<f>: links of f R_comm (0.95);
* pol:<dir>: the policy in <dir> (policy.pt, predictor.pt, card.yaml) on the plan point;
  pol:<dir>+track: the same with track_sensed_m 30.
"""
import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

torch.set_num_threads(1)
from scipy import stats

from plmarl_sitl.learning.eval.controllers import LearnedController, ServiceController
from plmarl_sitl.learning.eval.evaluate import controller_factory, needed_policies, run_method, tracking
from plmarl_sitl.learning.nn.io import load_policy
from plmarl_sitl.learning.nn.perception import plan_points
from plmarl_sitl.learning.train.teacher import joint_track, track_target, true_sense
from plmarl_sitl.model.service import LINK_FRAC
from plmarl_sitl.mission import load_mission
from plmarl_sitl.twin.rollout import rollout

HERE = Path(__file__).parent
S19 = HERE.parent.parent / "session19" / "move"


class Teach(ServiceController):
    def __init__(self, env, kind, k, leash, bounded, link=LINK_FRAC):
        super().__init__(env.mission)
        self.link = link
        self.env, self.kind, self.k, self.leash, self.bounded = env, kind, k, leash, bounded
        self.rs = float(env.mission.radii.sensing_m)

    @torch.no_grad()
    def act(self, obs):
        xy = self.targets.update(obs.t, obs.ego, obs.nbr_state, obs.nbr_t_rx, obs.demand, mask=obs.nbr_mask,
                                 alive=obs.alive, gossip=obs.gossip)
        r = self.k * self.rs
        sense = obs.sense if self.kind in ("sensed", "jsensed") else true_sense(self.env, r)
        if self.kind.startswith("j"):
            m = self.env.mission
            tgt = joint_track(xy, obs.ego, sense, obs.alive, radius_m=r, leash_m=self.leash,
                              link_m=LINK_FRAC * float(m.radii.comm_m), margin_m=self.link * float(m.radii.comm_m), apart_m=2.0 * self.rs)
            return self.targets.accel(obs.ego, tgt)
        tgt = track_target(self.env.mission, xy, obs.ego, sense, lambda: plan_points(self.targets), radius_m=r,
                           leash_m=self.leash, bounded=self.bounded)
        return self.targets.accel(obs.ego, tgt)


def factory(name, loaded):
    if name.startswith("teach-"):
        parts = name.split("-")
        kind, k, leash = parts[1], float(parts[2][1:]), float(parts[3][1:])
        bounded = not (len(parts) > 4 and parts[4] == "u")
        link = float(parts[4][1:]) if len(parts) > 4 and parts[4].startswith("l") else LINK_FRAC
        return lambda env: Teach(env, kind, k, leash, bounded, link)
    if name.startswith("pol:"):
        d, _, tr = name[4:].partition("+")
        lp = loaded[d]
        if tr:
            return lambda env: LearnedController(lp.tracker, lp.policy, tracking(env.mission))
        return lambda env: LearnedController(lp.tracker, lp.policy, env.mission)
    return controller_factory(name, loaded)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--missions", required=True)
    ap.add_argument("--methods", required=True)
    ap.add_argument("--episodes", type=int, default=20)
    ap.add_argument("--seed", type=int, default=5001)
    ap.add_argument("--tup", default="15")
    ap.add_argument("--out", default=None)
    ap.add_argument("--failure-prob", type=float, default=0.0)
    a = ap.parse_args()
    assert a.seed < 1_000_000_000, "probes use training twin seeds only"
    methods = a.methods.split(",")
    loaded = {p: load_policy(Path("policies") / p) for p in needed_policies(methods)}
    for m in methods:
        if m.startswith("pol:"):
            d = m[4:].partition("+")[0]
            loaded[d] = load_policy(Path(d))
    print(f"seed {a.seed} episodes {a.episodes}", flush=True)
    out = {}
    for mname in a.missions.split(","):
        for tup in [int(x) for x in a.tup.split(",")]:
            path = Path(mname) if "/" in mname else S19 / f"{mname}.yaml"
            m = load_mission(path).with_tup(tup)
            cov = {}
            for meth in methods:
                t0 = time.process_time()
                runs = rollout(m, factory(meth, loaded), a.episodes, a.seed, batch=a.episodes,
                               failure_prob=a.failure_prob)
                cov[meth] = np.concatenate([x.coverage[:, 50:].mean(-1).numpy() for x in runs])
                l2 = np.concatenate([x.lambda2[:, 50:].numpy() for x in runs])
                r = argparse.Namespace(lambda2=l2.mean(-1), split=(l2 <= 1e-6).mean(-1))
                cpu = time.process_time() - t0
                line = f"{mname} T_up {tup} {meth:28s} {cov[meth].mean():.4f} l2 {r.lambda2.mean():.2f} split {r.split.mean():.3f}"
                if meth != "service" and "service" in cov:
                    d = cov[meth] - cov["service"]
                    pw = stats.wilcoxon(cov[meth], cov["service"]).pvalue if np.any(d != 0) else 1.0
                    line += f"  d {d.mean():+.4f} w/l {(d > 0).sum()}/{(d < 0).sum()} pW {pw:.2g}"
                if meth not in ("service", "service-track") and "service-track" in cov:
                    d = cov[meth] - cov["service-track"]
                    line += f"  vs track {d.mean():+.4f} w/l {(d > 0).sum()}/{(d < 0).sum()}"
                print(line + f"  cpu {cpu:.0f}s", flush=True)
                out[f"{mname}@{tup}/{meth}"] = {"coverage": cov[meth].tolist(), "lambda2": r.lambda2.tolist(), "split": r.split.tolist()}
    if a.out:
        Path(a.out).write_text(json.dumps({"seed": a.seed, "episodes": a.episodes, "coverage": out}, indent=1))


if __name__ == "__main__":
    main()
