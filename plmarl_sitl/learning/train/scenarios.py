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
  (`users.rpgm_range_m`), the crowds the 30-s, 50-m demand map goes stale on;
* with probability `transit_share` (0 by default; `plmarl train --transit-share`), a long transit
  (issue 24.3, session 21): the area becomes a strip `transit_width_m` wide and as long as it must
  be, the scenario's C clusters a chain along it `transit_gap` R_comm apart (the longer gaps need
  a relay) and laterally anywhere in its middle half, and the swarm launches across the strip
  near one end, `transit_m` short of the chain's first cluster: a 0.5-1.5 km flight to the first
  cluster and 1-3 km to the last, over the other UAVs' clusters. End, orientation (along east or
  north) and all distances are drawn per batch; the launch is that line in every environment of
  the batch (no random launch) and the episode lasts `transit_episode_s`.

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
    transit_share: float = 0.0
    transit_m: tuple[float, float] = (500.0, 1500.0)  # launch line to the chain's first cluster, along the strip
    transit_gap: tuple[float, float] = (0.6, 1.2)  # between neighbouring clusters along the strip, in R_comm
    transit_width_m: tuple[float, float] = (350.0, 600.0)
    transit_episode_s: int = 300

    @classmethod
    def of(cls, trainer_args) -> ScenarioArgs:
        """The distribution a trainer's args ask for (`mappo.Args`, `imitation.ImitationArgs`: their
        moving and transit shares; the rest as drawn here)."""
        return cls(moving_share=trainer_args.moving_share, transit_share=trainer_args.transit_share)


# A transit scenario flies from its own launch line: the trainers give it no random launch (`random_launch`).
TRANSIT_NAME = "training_transit"


def random_launch(m: Mission, general: bool) -> bool:
    """Whether a trainer's episodes of scenario `m` launch from a random line: in the general
    scenarios yes, except a long transit, whose strip starts from its own launch line."""
    return general and m.name != TRANSIT_NAME


def trainer_scenario(mission: Mission, rng: np.random.Generator, trainer_args) -> Mission:
    """The scenario a trainer's batch flies (`mappo.Args`, `imitation.ImitationArgs`): with
    `general`, drawn by `training_mission` with the trainer's shares; else the mission as given
    (no draw)."""
    return training_mission(mission, rng, ScenarioArgs.of(trainer_args)) if trainer_args.general else mission


def training_mission(base: Mission, rng: np.random.Generator, args: ScenarioArgs = ScenarioArgs()) -> Mission:
    m = _scenario(base, rng, args)
    if args.moving_share > 0 and rng.random() < args.moving_share:  # no draw at all when off: the old stream
        speed = float(rng.uniform(*args.moving_speed_mps))
        reach = float(rng.uniform(*args.moving_range_m))
        m = dataclasses.replace(m, users=dataclasses.replace(m.users, mobility="rpgm", max_speed_mps=speed / RPGM_GROUP_SPEED,
                                                             rpgm_range_m=reach))
    if args.transit_share > 0 and rng.random() < args.transit_share:  # likewise
        m = _transit(m, rng, args)
    return m


def _transit(m: Mission, rng: np.random.Generator, args: ScenarioArgs) -> Mission:
    """The scenario's N and C on a long strip, launched near one end (the module's docstring)."""
    c = max(1, m.users.count // m.users.cluster_size)
    width = float(rng.uniform(*args.transit_width_m))
    first = float(rng.uniform(*args.transit_m))
    gaps = rng.uniform(*args.transit_gap, size=c - 1) * m.radii.comm_m
    lateral = rng.uniform(0.25, 0.75, size=c) * width
    start = 200.0  # the launch line's distance from the strip's end
    along = start + first + np.concatenate([[0.0], np.cumsum(gaps)])
    length = float(along[-1] + 300.0)
    if rng.random() < 0.5:  # launched from the other end
        along, start = length - along, length - start
    centres = np.stack([lateral, along], -1)
    launch_across, launch_along = width / 2, start
    if rng.random() < 0.5:  # the strip along north instead of east
        centres = centres[:, ::-1]
        area = dataclasses.replace(m.area, north_m=length, east_m=width)
        launch = dataclasses.replace(m.launch, north_m=launch_along, east_m=launch_across, bearing_deg=90.0)
    else:
        area = dataclasses.replace(m.area, north_m=width, east_m=length)
        launch = dataclasses.replace(m.launch, north_m=launch_across, east_m=launch_along, bearing_deg=0.0)
    users = dataclasses.replace(m.users, count=c * m.users.cluster_size, layout="fixed",
                                cluster_centers=tuple((float(a), float(b)) for a, b in centres))
    return dataclasses.replace(m, name=TRANSIT_NAME, area=area, users=users, launch=launch,
                               timing=dataclasses.replace(m.timing, episode_s=args.transit_episode_s))


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
    transit = {}
    if args.transit_share > 0:
        transit = {"transit": "with probability transit_share, a strip transit_width_m wide, the C clusters a chain along "
                              "it transit_gap R_comm apart, launched across it near one end transit_m short of the first "
                              "cluster (end and orientation random), episodes of transit_episode_s"}
    else:  # the card of before long transits, key for key
        for k in ("transit_share", "transit_m", "transit_gap", "transit_width_m", "transit_episode_s"):
            fields.pop(k)
    return {
        "scenarios": "per rollout batch: N uniform in n_uavs, C clusters of 60 uniform in [max(2, N - 2), min(8, N + 2)] on "
                     "the twin's random connected layout (a new layout per environment); the mission itself with "
                     "probability mission_share",
        **fields,
        "launch": "a random line centre and orientation per environment (CoverageEnv(random_launch=True))",
        "mobility": "mixed: Gauss-Markov, Random Waypoint, RPGM per environment",
        **moving,
        **transit,
        "tup_s": list(tup_choices),
        "failure": failure,
    }
