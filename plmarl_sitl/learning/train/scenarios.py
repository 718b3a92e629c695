"""The training distribution of issue 12: scenarios a policy cannot memorise.

Per rollout batch (every environment of a batch shares N, because the twin's tensors
are (B, N, ...)), `training_mission` draws from the mission given to `plmarl train`:

* the swarm size N uniformly in `n_uavs` (3..8);
* the number of user clusters C (60 users each) uniformly in [max(2, N - 2), min(8, N + 2)],
  on the twin's `random` connected layout (a new layout in every environment);
* with probability `mission_share`, the mission itself instead (its N and layout), so the
  paper map stays in the distribution;
* mixed mobility (Gauss-Markov, Random Waypoint, RPGM per environment).

The launch line's centre and orientation are drawn per environment by the twin
(`CoverageEnv(random_launch=True)`); T_up and the failure curriculum are drawn by the
trainers as before.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from plmarl_sitl.mission import Mission


@dataclass(frozen=True)
class ScenarioArgs:
    n_uavs: tuple[int, int] = (3, 8)
    clusters: tuple[int, int] = (2, 8)
    mission_share: float = 0.15


def training_mission(base: Mission, rng: np.random.Generator, args: ScenarioArgs = ScenarioArgs()) -> Mission:
    users = dataclasses.replace(base.users, mobility="mixed")
    if rng.random() < args.mission_share:
        return dataclasses.replace(base, users=users)
    n = int(rng.integers(args.n_uavs[0], args.n_uavs[1] + 1))
    c = int(rng.integers(max(args.clusters[0], n - 2), min(args.clusters[1], n + 2) + 1))
    users = dataclasses.replace(users, count=c * users.cluster_size, layout="random", cluster_centers=())
    # Scripted failures and events name UAV indices of the base mission: the curriculum's own failures replace them.
    return dataclasses.replace(base, n_uavs=n, users=users, failures=(), events=())


def describe_distribution(general: bool, tup_choices: tuple[int, ...], failure: dict, args: ScenarioArgs = ScenarioArgs()) -> dict:
    """The training distribution as the policy card records it."""
    if not general:
        return {"scenarios": "the mission as given, from its launch line", "tup_s": list(tup_choices), "failure": failure}
    return {
        "scenarios": "per rollout batch: N uniform in n_uavs, C clusters of 60 uniform in [max(2, N - 2), min(8, N + 2)] on "
                     "the twin's random connected layout (a new layout per environment); the mission itself with "
                     "probability mission_share",
        **{k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(args).items()},
        "launch": "a random line centre and orientation per environment (CoverageEnv(random_launch=True))",
        "mobility": "mixed: Gauss-Markov, Random Waypoint, RPGM per environment",
        "tup_s": list(tup_choices),
        "failure": failure,
    }
