"""Prototype (session 28): the PL-MARL policy on station, the plan follower's command in transit.
An agent farther than D m (horizontal) from its plan point flies goto_accel to it, exactly the
plan-aware nominal (model/plan_motion.py); within D the learnt policy acts. Flies suite families
exactly as `plmarl suite --seed S --episodes E` (same twin seeds), records per-episode coverage
after 50 s and false declarations (live ids ever declared by some live copy)."""
import argparse, json, sys
import numpy as np, torch
from plmarl_sitl.learning.eval.controllers import LearnedController
from plmarl_sitl.learning.eval.evaluate import controller_factory
from plmarl_sitl.learning.eval.suite import load_suite, episodes_per_mission, twin_seeds
from plmarl_sitl.learning.nn.io import load_policy
from plmarl_sitl.twin.env import CoverageEnv


class Hybrid(LearnedController):
    def __init__(self, tracker, policy, mission, transit_m):
        super().__init__(tracker, policy, mission)
        self.transit_m = transit_m

    @torch.no_grad()
    def act(self, obs):
        a = self.policy(self.perceive(obs))
        plan = self.perceive.plan
        target = plan.last
        far = ((obs.ego[..., :2] - target).norm(dim=-1) > self.transit_m).unsqueeze(-1)
        return torch.where(far, plan.accel(obs.ego, target.to(obs.ego.dtype)).to(a.dtype), a)


def make(method, loaded):
    if "@transit" in method:  # the product: method on the mission with transit_plan_m
        base, d = method.split("@transit")
        f = controller_factory(base, loaded)
        return lambda env: f(_Env(env, float(d)))
    if method.startswith("hybrid"):
        d = float(method.removeprefix("hybrid"))
        lp = loaded["pl-marl"]
        return lambda env: Hybrid(lp.tracker, lp.policy, env.mission, d)
    return controller_factory(method, loaded)


class _Env:
    """The env with its mission's transit_plan_m set (controller factories read env.mission)."""
    def __init__(self, env, d):
        self._env, self.mission = env, env.mission.with_transit_plan(d)

    def __getattr__(self, k):
        return getattr(self._env, k)


def fly(mission, mk, n, seed, fp):
    env = CoverageEnv(mission, n, seed, track_lambda2=True, failure_prob=fp)
    ctl = mk(env); ctl.reset(); obs = env.observe()
    cover, ids = [], torch.zeros(n, env.n, dtype=torch.bool)
    with torch.inference_mode():
        while not env.done:
            obs, _, info = env.step(ctl.act(obs))
            cover.append(info.coverage)
            g = env.gossip
            if g is not None:
                al = env.alive
                ids |= (g.failed & al.unsqueeze(-1) & al.unsqueeze(1) & ~torch.eye(env.n, dtype=torch.bool)).any(1)
    tr = torch.cat(cover, -1).numpy()
    return tr[:, 50:].mean(1).tolist(), ids.sum(-1).tolist(), tr


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="+", required=True)
    ap.add_argument("--families", nargs="+", required=True)
    ap.add_argument("--tups", type=int, nargs="+", default=[15, 50])
    ap.add_argument("--methods", nargs="+", default=["pl-marl", "hybrid50", "service"])
    ap.add_argument("--episodes", type=int, default=30)
    a = ap.parse_args()
    _, fams = load_suite("/work/main/missions/suite/suite.yaml")
    out = []
    for seed in a.seeds:
        for fname in a.families:
            fam = fams[fname]
            counts = episodes_per_mission(a.episodes, len(fam.missions))
            seeds = twin_seeds(seed, a.episodes, fam)
            loaded = {"pl-marl": load_policy("/work/main/policies/pl-marl", fam.missions[0])}
            tups = [fam.spec.tup] if getattr(fam.spec, "tup", None) else a.tups
            for tup in a.tups:
                for meth in a.methods:
                    cov, ids, after = [], [], []
                    fail_s = fam.spec.failure_at_s or (100.0 if fam.spec.failure_prob > 0 else None)  # as suite.summarise
                    fail_s = None if fail_s is None else int(fail_s)
                    for m, e, s in zip(fam.missions, counts, seeds):
                        if e == 0: continue
                        c, i, tr = fly(m.with_tup(tup), make(meth, loaded), e, s[0], fam.spec.failure_prob)
                        cov += c; ids += i
                        if fail_s is not None:
                            after += tr[:, fail_s - 1 + 30:].mean(1).tolist()
                    out.append({"seed": seed, "family": fname, "tup": tup, "method": meth, "cov": cov, "false_ids": ids, "after_fail30": after})
                    print(f"{seed} {fname} T{tup} {meth}: {np.mean(cov):.4f} false {sum(ids)}", file=sys.stderr, flush=True)
    json.dump(out, sys.stdout)


main()
