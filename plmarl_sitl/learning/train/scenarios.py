"""The training distribution of issue 12: scenarios a policy cannot memorise.

Per rollout batch (every environment of a batch shares N, because the twin's tensors
are (B, N, ...)), `training_mission` draws from the mission given to `plmarl train`:

* the swarm size N uniformly in `n_uavs` (3..8);
* the number of user clusters C (60 users each) uniformly in [max(2, N - 2), min(8, N + 2)],
  on the twin's `random` connected layout (a new layout in every environment);
* with probability `mission_share`, the mission itself instead (its N and layout), so the
  paper map stays in the distribution;
* mixed mobility (Gauss-Markov, Random Waypoint, RPGM per environment);
* with probability `moving_share` (0 by default; `plmarl train --moving-share`), moving demand
  (issue 24.3): RPGM groups walking at a speed drawn in `moving_speed_mps` (the group's speed,
  0.6 of the users' max_speed_mps) up to a range drawn in `moving_range_m` from home
  (`users.rpgm_range_m`), the crowds the 30-s, 50-m demand map goes stale on.

The launch line's centre and orientation are drawn per environment by the twin
(`CoverageEnv(random_launch=True)`); T_up and the failure curriculum are drawn by the
trainers as before.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from plmarl_sitl.mission import Mission
from plmarl_sitl.model.users import RPGM_GROUP_SPEED


@dataclass(frozen=True)
class ScenarioArgs:
    n_uavs: tuple[int, int] = (3, 8)
    clusters: tuple[int, int] = (2, 8)
    mission_share: float = 0.15
    moving_share: float = 0.0
    moving_speed_mps: tuple[float, float] = (1.5, 3.0)  # the RPGM group's speed
    moving_range_m: tuple[float, float] = (200.0, 400.0)




def training_mission(base: Mission, rng: np.random.Generator, args: ScenarioArgs = ScenarioArgs()) -> Mission:
    m = _scenario(base, rng, args)
    if args.moving_share > 0 and rng.random() < args.moving_share:  # no draw at all when off: the old stream
        speed = float(rng.uniform(*args.moving_speed_mps))
        reach = float(rng.uniform(*args.moving_range_m))
        m = dataclasses.replace(m, users=dataclasses.replace(m.users, mobility="rpgm", max_speed_mps=speed / RPGM_GROUP_SPEED,
                                                             rpgm_range_m=reach))
    return m


def _scenario(base: Mission, rng: np.random.Generator, args: ScenarioArgs) -> Mission:
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
    fields = {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(args).items()}
    moving = {}
    if args.moving_share > 0:
        moving = {"moving": "with probability moving_share, RPGM groups walking at a speed in moving_speed_mps up to a "
                            "range in moving_range_m from home (users.rpgm_range_m)"}
    else:  # the card of before moving demand, key for key
        for k in ("moving_share", "moving_speed_mps", "moving_range_m"):
            fields.pop(k)
    return {
        "scenarios": "per rollout batch: N uniform in n_uavs, C clusters of 60 uniform in [max(2, N - 2), min(8, N + 2)] on "
                     "the twin's random connected layout (a new layout per environment); the mission itself with "
                     "probability mission_share",
        **fields,
        "launch": "a random line centre and orientation per environment (CoverageEnv(random_launch=True))",
        "mobility": "mixed: Gauss-Markov, Random Waypoint, RPGM per environment",
        **moving,
        "tup_s": list(tup_choices),
        "failure": failure,
    }
