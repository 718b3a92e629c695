# ruff: noqa  (a scratch probe kept to reproduce the numbers of session 21; not product code)
"""Session 21 probe (training twin seeds only): `service` and learnt policies from directories on the
same episodes, paired per episode.

    PYTHONPATH=. python docs/results/issue24/session21/learn/probe.py \
        --missions docs/results/issue24/session21/learn/probe_strip_random.yaml,... \
        --methods service,pol:policies/pl-marl,pol:runs/l21/t25-s23 --episodes 20 --seed 5001 --tup 15 --out X.json

Coverage is the suite's (mean C(t), t > 50 s); split is the share of those seconds with lambda_2 = 0.
Every policy is compared with `service` and with the first `pol:` (the current default).
"""
import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

torch.set_num_threads(1)
from scipy import stats

from plmarl_sitl.learning.eval.controllers import LearnedController
from plmarl_sitl.learning.eval.evaluate import controller_factory, needed_policies
from plmarl_sitl.learning.nn.io import load_policy
from plmarl_sitl.mission import load_mission
from plmarl_sitl.twin.rollout import rollout

S19 = Path(__file__).parent.parent.parent / "session19" / "move"


def factory(name, loaded):
    if name.startswith("pol:"):
        lp = loaded[name[4:]]
        return lambda env: LearnedController(lp.tracker, lp.policy, env.mission)
    return controller_factory(name, loaded)


def paired(a, b):
    d = a - b
    p = stats.wilcoxon(a, b).pvalue if np.any(d != 0) else 1.0
    return f"{d.mean():+.4f} ({(d > 0).sum()}/{(d < 0).sum()}, {p:.2g})"


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--missions", required=True)
    ap.add_argument("--methods", required=True)
    ap.add_argument("--episodes", type=int, default=20)
    ap.add_argument("--seed", type=int, default=5001)
    ap.add_argument("--tup", default="15")
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    assert a.seed < 1_000_000_000, "probes use training twin seeds only"
    methods = a.methods.split(",")
    loaded = {p: load_policy(Path("policies") / p) for p in needed_policies(methods)}
    for m in methods:
        if m.startswith("pol:"):
            loaded[m[4:]] = load_policy(Path(m[4:]))
    ref = next((m for m in methods if m.startswith("pol:")), None)
    print(f"seed {a.seed} episodes {a.episodes}", flush=True)
    out = {}
    for mname in a.missions.split(","):
        path = Path(mname) if "/" in mname else S19 / f"{mname}.yaml"
        for tup in [int(x) for x in a.tup.split(",")]:
            m = load_mission(path).with_tup(tup)
            cov = {}
            for meth in methods:
                t0 = time.time()
                runs = rollout(m, factory(meth, loaded), a.episodes, a.seed, batch=a.episodes)
                cov[meth] = np.concatenate([x.coverage[:, 50:].mean(-1).numpy() for x in runs])
                l2 = np.concatenate([x.lambda2[:, 50:].numpy() for x in runs])
                split = (l2 <= 1e-6).mean(-1)
                line = f"{m.name} T_up {tup} {meth:34s} {cov[meth].mean():.4f} l2 {l2.mean():.2f} split {split.mean():.3f}"
                if meth != "service" and "service" in cov:
                    line += "  vs service " + paired(cov[meth], cov["service"])
                if ref and meth != ref and meth.startswith("pol:") and ref in cov:
                    line += "  vs default " + paired(cov[meth], cov[ref])
                print(line + f"  {time.time() - t0:.0f}s", flush=True)
                out[f"{m.name}@{tup}/{meth}"] = {"coverage": cov[meth].tolist(), "lambda2": l2.mean(-1).tolist(),
                                                  "split": split.tolist()}
    if a.out:
        Path(a.out).write_text(json.dumps({"seed": a.seed, "episodes": a.episodes, "coverage": out}, indent=1))


if __name__ == "__main__":
    main()
