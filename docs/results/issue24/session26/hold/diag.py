"""H-hold26 diagnostic (after the judgement numbers; changes no criterion): for each (copy, suspect) pair HOLD keeps
undeclared at a decision, was the suspect alive or dead, and were the teammates f that allowed the hold alive (a live f
out of the copy's hearing: the intended case needs f dead) or dead (f a failed UAV the copy has not declared)?
Books per episode: held_{live,dead}_j x {only live f, some dead f}. Same episodes as runner.py (lr_hold only).

    PYTHONPATH=. python docs/results/issue24/session26/hold/diag.py --seeds 29 30 --episodes 30 --tups 50 \
        --families failure_2of6 failure_transit --variants lr_hold > diag.json 2> diag.log
"""
import sys

import numpy as np
import torch

sys.path.insert(0, __file__.rsplit("/", 1)[0])
import runner  # noqa: E402

from plmarl_sitl.learning.nn import plan as plan_mod  # noqa: E402

K = ("j_live_f_live_only", "j_live_f_some_dead", "j_dead_f_live_only", "j_dead_f_some_dead")
C = {"counts": None}
h0 = plan_mod.held_for_repairs


def held(sus, failed, points, t_rx, s, link_m):  # noqa: ANN001, ANN201
    out = h0(sus, failed, points, t_rx, s, link_m)
    alive = runner.HELD["alive"]
    if alive is not None and C["counts"] is not None:
        n = sus.shape[-1]
        eye = torch.eye(n, dtype=torch.bool)
        pts = points.double()
        cand = ~failed & ~pts.isnan().any(-1) & (t_rx != float(s)) & ~sus & ~eye  # (B, a, f)
        d2 = ((pts.unsqueeze(-2) - pts.unsqueeze(-3)) ** 2).sum(-1)
        q = (d2 <= float(link_m) ** 2) & ~eye & cand.unsqueeze(-2)  # (B, a, j, f) f allows holding j
        dead_f = (q & ~alive.view(alive.shape[0], 1, 1, n)).any(-1)
        m = out & alive.unsqueeze(-1)  # held by a live copy
        jl = alive.unsqueeze(1)
        for k, sel in zip(K, (m & jl & ~dead_f, m & jl & dead_f, m & ~jl & ~dead_f, m & ~jl & dead_f), strict=True):
            C["counts"][k] += sel.sum((-1, -2)).numpy()
    return out


fly0 = runner.fly


def fly(mission, make, episodes, seed, failure_prob, fail_s):  # noqa: ANN001, ANN201
    C["counts"] = {k: np.zeros(episodes, int) for k in K}
    r = fly0(mission, make, episodes, seed, failure_prob, fail_s)
    r.update({k: v.tolist() for k, v in C["counts"].items()})
    print("   " + " ".join(f"{k} {int(v.sum())}" for k, v in C["counts"].items()), file=sys.stderr, flush=True)
    return r


runner.fly = fly
_count = runner._count_held


def _count_held() -> None:
    plan_mod.held_for_repairs = held  # the diagnostic wrapper first,
    _count()  # then the runner's counter around it


runner._count_held = _count_held
if __name__ == "__main__":
    sys.exit(runner.main())
