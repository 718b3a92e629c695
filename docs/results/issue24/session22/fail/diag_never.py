"""Session 22 diagnostic: the failed UAVs some survivor never learns (service, T_up 50, options off); per instant their distance to each survivor, who knows, the may_predict guard, the predicted distance.

    PYTHONPATH=. python docs/results/issue24/session22/fail/diag_never.py SEED VARIANT(0 a, 1 b)
"""
import sys
import numpy as np, torch
from plmarl_sitl.learning.eval.controllers import ServiceController
from plmarl_sitl.learning.train.seeds import suite_twin_seed
from plmarl_sitl.mission import load_mission
from plmarl_sitl.twin.env import CoverageEnv
from plmarl_sitl.model.gossip import may_predict
seed, v = int(sys.argv[1]), int(sys.argv[2])
eps = 10
path = ["missions/suite/failure_2of6_a.yaml", "missions/suite/failure_2of6_b.yaml"][v]
m = load_mission(path).with_tup(50)
env = CoverageEnv(m, eps, suite_twin_seed(seed, v))
ctl = ServiceController(m); ctl.reset(); obs = env.observe()
R = float(m.radii.comm_m)
snap = {}
with torch.inference_mode():
    while not env.done:
        obs, _, info = env.step(ctl.act(obs))
        if obs.t in (99, 101, 103, 151, 153, 201, 203, 251, 299):
            snap[obs.t] = dict(pos=env.pos[..., :2].clone(), alive=env.alive.clone(), failed=env.gossip.failed.clone(),
                               mp=may_predict(env.gossip.heard_rank, env.gossip.rank, obs.t - obs.t % 50).clone(),
                               pred={k: ctl.targets.plans.motion.at(k)[..., :2].clone() for k in (100, 150, 200, 250) if k < obs.t and k in ctl.targets.plans.motion.kept},
                               tgt=ctl.targets.last.clone())
print("R_comm", R)
for e in range(eps):
    alive = env.alive[e]
    dead = np.flatnonzero(~alive.numpy())
    surv = np.flatnonzero(alive.numpy())
    f = env.gossip.failed[e]
    undeclared = [y for y in dead if not bool(f[surv][:, y].all())]
    if not undeclared:
        continue
    print(f"episode {e}: dead {dead.tolist()} undeclared-by-all {undeclared}")
    for t, s in snap.items():
        p = s['pos'][e]
        for y in undeclared:
            d = ((p[surv] - p[y]) ** 2).sum(-1).sqrt().numpy().round(0)
            knows = [int(s['failed'][e, i, y]) for i in surv]
            mp = [int(s['mp'][e, i, y]) for i in surv]
            inst = t - t % 50
            pr = ""
            if inst in s['pred']:
                pp = s['pred'][inst][e]  # (A, n, 2)
                # predicted y by each survivor copy vs predicted own
                dpred = [float(((pp[i, y] - pp[i, i]) ** 2).sum().sqrt()) for i in surv]
                pr = f" pred_d {np.round(dpred,0).tolist()}"
            print(f"  t={t} y={y} surv {surv.tolist()} d {d.tolist()} knows {knows} may_pred {mp}{pr}")
        print(f"  t={t} failed matrix rows(surv): {[np.flatnonzero(s['failed'][e,i].numpy()).tolist() for i in surv]}")
