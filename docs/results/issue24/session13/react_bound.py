"""What instant failure knowledge is worth (issue 24 part 3): the CTDE teacher of
`plmarl train --teacher react` (learning/train/teacher.py: the plan re-solved the decision a UAV
dies, from true positions) flown as a controller, beside `service` (the same plan follower,
which learns of failures from missed instants and gossip), on the suite's episodes.

It bounds what a student imitating that teacher can gain over `service`.

    PYTHONPATH=. python docs/results/issue24/session13/react_bound.py failure_2of6,failure_transit,diffuse_failure \
        --tup 15,50 --episodes 20 --seed 2413 > out.json
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import torch

from plmarl_sitl.config import PROJECT_SUITE
from plmarl_sitl.learning.eval.controllers import ServiceController
from plmarl_sitl.learning.eval.evaluate import run_method
from plmarl_sitl.learning.eval.stats import mann_whitney_p, mean_ci95
from plmarl_sitl.learning.eval.suite import BATCH, episodes_per_mission, family_tups, load_suite, twin_seeds
from plmarl_sitl.learning.train.teacher import ReactTargets


class ReactController:
    def __init__(self, mission) -> None:  # noqa: ANN001
        self.targets = ReactTargets.of(mission)

    def reset(self) -> None:
        self.targets.reset()

    @torch.no_grad()
    def act(self, obs) -> torch.Tensor:  # noqa: ANN001
        return self.targets.accel(obs.ego, self.targets.update_true(obs))


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("families")
    p.add_argument("--tup", default="15,50")
    p.add_argument("--episodes", type=int, default=20)
    p.add_argument("--seed", type=int, default=2413)
    a = p.parse_args()
    torch.set_num_threads(1)
    _, fams = load_suite(PROJECT_SUITE)
    out = []
    for name in a.families.split(","):
        fam = fams[name]
        seeds = twin_seeds(a.seed, a.episodes, fam)
        counts = episodes_per_mission(a.episodes, len(fam.missions))
        for tup in family_tups(fam, [int(x) for x in a.tup.split(",")]):
            cov = {}
            for label, make in (("service", lambda env: ServiceController(env.mission)),
                                ("react-teacher", lambda env: ReactController(env.mission))):
                t0 = time.time()
                parts = [run_method(m.with_tup(tup), make, e, s[0], batch=BATCH, failure_prob=fam.spec.failure_prob).coverage
                         for m, e, s in zip(fam.missions, counts, seeds, strict=True) if e > 0]
                cov[label] = np.concatenate(parts)
                print(f"{name} T_up {tup} {label}: {cov[label].mean():.4f} ({time.time() - t0:.0f} s)", flush=True)
            d = cov["react-teacher"] - cov["service"]
            out.append({"family": name, "tup": tup, "episodes": a.episodes, "seed": a.seed,
                        **{k: {"mean": mean_ci95(v)[0], "ci95": list(mean_ci95(v)[1])} for k, v in cov.items()},
                        "paired_difference": {"mean": mean_ci95(d)[0], "ci95": list(mean_ci95(d)[1]),
                                              "wins": int((d > 0).sum()), "losses": int((d < 0).sum())},
                        "p_mann_whitney": mann_whitney_p(cov["react-teacher"], cov["service"])})
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
