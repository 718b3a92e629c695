"""Random search for states where k steps of dt/k differ from one step of dt (float64).

The hypothesis test in tests/model/test_vehicle.py runs a few hundred examples per CI run;
this runs many more, with speeds and altitudes biased onto the limits. As a test it checks
800 cases (~20 ms each); by hand it takes more and prints how many disagree by more than 1e-6:

    python tests/model/test_substep_check.py --cases 60000 --seed 0
"""

from __future__ import annotations

import argparse
import math
import random

import pytest
import torch

from plmarl_sitl.model.vehicle import Limits, step_point_mass

LIM = Limits(max_speed=20.0, max_accel=5.0, alt_min=40.0, alt_max=150.0)


def case(rng: random.Random) -> tuple[float, list[float], list[float], float, int]:
    alt = rng.choice([40.0, 150.0, 40.0 + rng.choice([1e-9, 1e-6, 1e-3]), 150.0 - rng.choice([1e-9, 1e-6, 1e-3]), rng.uniform(40, 150)])
    d = [rng.gauss(0, 1) for _ in range(3)]
    n = math.sqrt(sum(x * x for x in d)) or 1.0
    speed = 20.0 * (1 + rng.choice([0, 1e-12, -1e-12, 1e-9, -1e-9, -1e-7, -1e-6, 1e-6, 0.5, -rng.random()]))
    vel = [x / n * speed for x in d]
    acc = [rng.uniform(-30, 30) if rng.random() < 0.2 else rng.uniform(-6, 6) for _ in range(3)]
    return alt, vel, acc, rng.choice([0.02, 0.1, 0.5, 1.0, rng.uniform(0.01, 10)]), rng.randint(2, 13)


def disagreements(cases: int, seed: int, show: int = 5) -> int:
    """How many of `cases` random cases disagree; the first `show` are printed."""
    rng = random.Random(seed)
    bad = 0
    for _ in range(cases):
        alt, vel, acc, dt, k = case(rng)
        pos = torch.tensor([[10.0, -5.0, -alt]], dtype=torch.float64)
        v0 = torch.tensor([vel], dtype=torch.float64)
        a = torch.tensor([acc], dtype=torch.float64)
        p1, v1 = step_point_mass(pos, v0, a, dt, LIM)
        p2, v2 = pos, v0
        for _ in range(k):
            p2, v2 = step_point_mass(p2, v2, a, dt / k, LIM)
        if not (torch.allclose(p1, p2, atol=1e-6) and torch.allclose(v1, v2, atol=1e-6)):
            bad += 1
            if bad <= show:
                print("disagree:", dict(alt=alt, vel=vel, acc=acc, dt=dt, k=k))
    return bad


@pytest.mark.slow
def test_substeps_agree_with_one_step_on_random_cases_at_the_limits() -> None:
    assert disagreements(cases=800, seed=0) == 0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cases", type=int, default=60000)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    print(f"{args.cases} cases, seed {args.seed}: {disagreements(args.cases, args.seed)} disagree")


if __name__ == "__main__":
    main()
