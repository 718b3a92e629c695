"""Fly one suite family batch (tuning seed) with two controllers; per episode and second record
coverage, positions, alive, the union of failed declarations of live copies, lambda2; print a
per-episode digest for chosen episodes."""
import sys, json
import numpy as np, torch
from plmarl_sitl.learning.eval.evaluate import controller_factory
from plmarl_sitl.learning.eval.suite import load_suite, episodes_per_mission, twin_seeds
from plmarl_sitl.learning.nn.io import load_policy
from plmarl_sitl.twin.env import CoverageEnv

fam_name, tup, seed, eps = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), [int(x) for x in sys.argv[4].split(",")]
methods = sys.argv[5].split(",") if len(sys.argv) > 5 else ["pl-marl", "service"]
spec, fams = load_suite("/work/main/missions/suite/suite.yaml")
fam = fams[fam_name]
import os
V = int(os.environ.get("V", "0"))
m = fam.missions[V].with_tup(tup)
n_ep = episodes_per_mission(30, len(fam.missions))[V]
s = twin_seeds(seed, 30, fam)[V][0]
loaded = {"pl-marl": load_policy("/work/main/policies/pl-marl", m)}
out = {}
for meth in methods:
    env = CoverageEnv(m, n_ep, s, track_lambda2=True, failure_prob=fam.spec.failure_prob)
    ctl = controller_factory(meth, loaded)(env); ctl.reset(); obs = env.observe()
    rec = {"cov": [], "pos": [], "alive": [], "decl": [], "l2": [], "tgt": []}
    with torch.inference_mode():
        while not env.done:
            obs, _, info = env.step(ctl.act(obs))
            rec["cov"].append(info.coverage.numpy().copy())
            rec["pos"].append(obs.ego[..., :2].numpy().copy() if obs.ego.dim() == 3 else obs.ego.numpy().copy())
            rec["alive"].append(env.alive.numpy().copy())
            g = env.gossip
            if g is not None:
                a = env.alive
                rec["decl"].append((g.failed & a.unsqueeze(-1)).numpy().copy())  # [E, knower, identity]
            l2 = getattr(info, "lambda2", None)
            rec["l2"].append(None if l2 is None else l2.numpy().copy())
    out[meth] = rec
np.save(f"/work/notes/s28/diag/{fam_name}_{tup}_{seed}_v{V}.npy", out, allow_pickle=True)
for e in eps:
    print(f"=== episode {e}")
    for meth, rec in out.items():
        cov = np.concatenate([c[e].reshape(-1) for c in rec["cov"]])
        print(meth, "cov after50 %.4f" % cov[50:].mean(), "per 25 s:", np.round(cov[::25], 3))
        decl = np.array(rec["decl"])[:, e]  # T, n, n
        alive = np.array(rec["alive"])[:, e]
        T = decl.shape[0]
        for t in range(T):
            new = decl[t] & ~(decl[t - 1] if t else np.zeros_like(decl[t]))
            for k, j in zip(*np.nonzero(new)):
                print(f"   t={3*(t+1)}s knower {k} declares {j} ({'DEAD' if not alive[t, j] else 'live'})")
