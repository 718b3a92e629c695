"""Warm start for MAPPO: imitate a teacher (DAgger; the team plan, or the greedy reference),
centralised knowledge used in training only.

Why: with Table I's budget (1000 episodes, lr 1e-4) MAPPO from scratch settles in a local
optimum where the four symmetric agents split over the two clusters nearest the launch
line (about 0.5 coverage; see docs/RESULTS.md). The greedy reference ("the Oracle" before
issue 24; global knowledge, greedy placement + Hungarian assignment) is a teacher that is available in the DT at
training time, exactly like the centralised critic: the student acts on its OWN local
inputs (own state, beliefs from its tracker, local sensing, fail flag), so nothing about
decentralised execution changes.

DAgger (Ross et al. 2011): round 0 rolls out the teacher, later rounds roll out the
student (with probability beta per environment the teacher still drives), every visited
state is labelled with the teacher's action, the dataset is aggregated and the actor's
mean is regressed on the labels (MSE in normalised action units).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from plmarl_sitl.learning.nn.belief import BeliefTracker
from plmarl_sitl.learning.nn.contract import PolicyForm
from plmarl_sitl.learning.nn.features import FeatureScales, policy_input
from plmarl_sitl.learning.nn.perception import Perception
from plmarl_sitl.learning.nn.policy import Actor
from plmarl_sitl.learning.train.scenarios import random_launch, trainer_scenario
from plmarl_sitl.learning.train.seeds import training_twin_seed
from plmarl_sitl.learning.train.teacher import ReactTargets, joint_track
from plmarl_sitl.mission import Failure, Mission
from plmarl_sitl.model.service import LINK_FRAC
from plmarl_sitl.twin.env import CoverageEnv
from plmarl_sitl.twin.greedy import GreedyController


@dataclass
class ImitationArgs:
    rounds: int = 4
    episodes_per_round: int = 32
    epochs: int = 30
    batch: int = 1024
    lr: float = 1e-3
    failure_prob: float = 0.2
    tup_choices: tuple[int, ...] = (5, 10, 15, 20, 25, 30, 35, 40, 45, 50)
    seed: int = 0
    # 1: one T_up per round, drawn at random (4 rounds may miss whole T_up ranges). k > 1:
    # each round's episodes are split into k batches whose T_up walk through a shuffled
    # cycle of tup_choices, so every T_up is imitated equally often.
    tup_chunks: int = 1
    # True: every batch draws its scenario (N, clusters, layout) and random launch lines
    # (plmarl_sitl.learning.train.scenarios); False: the mission as given.
    general: bool = True
    # The teacher: "oracle" = the greedy reference's action from the current global state
    # (GreedyController.act_from_state; the key keeps the name recorded in older cards); "plan" = fly to the agent's own team-plan point
    # (model/service.py), a teacher that uses only what the student has.
    teacher: str = "plan"
    # "react" (issue 24, CTDE): the plan re-solved the second a UAV fails, from the survivors'
    # true positions (learning/train/teacher.py); the student keeps its own perception.
    # Failures of the curriculum: "random", one random UAV at t = 100 s with failure_prob;
    # "scripted", every batch 1 or 2 UAVs (at most N - 2) fail at one second drawn in
    # failure_window_s (in transit early, on station later).
    failures: str = "random"
    failure_window_s: tuple[int, int] = (20, 160)
    # "track" (issue 24.3, CTDE): the plan point moved toward the users the UAV senses by at most
    # track_m, each UAV as far as the team's true chosen points stay linked and spaced
    # (learning/train/teacher.py::joint_track); the student sees only its own perception (the
    # unshifted plan point, its sensing, its beliefs).
    track_m: float = 30.0
    track_link_frac: float = LINK_FRAC  # the "track" teacher's link length, in R_comm (smaller: a margin)
    # ScenarioArgs.moving_share: the share of batches with moving demand (general scenarios only).
    moving_share: float = 0.0
    # ScenarioArgs.transit_share: the share of batches with a long transit (general scenarios only).
    transit_share: float = 0.0


INPUTS = ("ego", "nbr", "rel", "mask", "tok", "tok_mask")  # the actor's inputs, in order (policy_input)


def scripted_failures(m: Mission, rng: np.random.Generator, window: tuple[int, int]) -> Mission:
    """The mission with 1 or 2 of its UAVs (at most N - 2) failing at one second in `window`."""
    k = int(rng.integers(1, min(2, m.n_uavs - 2) + 1)) if m.n_uavs > 2 else 0
    at = float(rng.integers(window[0], window[1] + 1))
    uavs = rng.choice(m.n_uavs, size=k, replace=False)
    return dataclasses.replace(m, failures=tuple(Failure(at_s=at, uav=int(u)) for u in sorted(uavs)))


def cat_slots(parts: list[torch.Tensor]) -> torch.Tensor:
    """Concatenate samples of different swarm sizes: (S_k, M_k, ...) -> (sum S_k, max M_k, ...),
    padded with zeros / False (masked neighbour slots, ignored by the policy)."""
    m = max(x.shape[1] for x in parts)
    return torch.cat([torch.cat([x, x.new_zeros((x.shape[0], m - x.shape[1]) + tuple(x.shape[2:]))], 1) for x in parts])


def imitate_oracle(
    actor: Actor, tracker: BeliefTracker, mission: Mission, args: ImitationArgs, log: Callable[[str], None] = print,
    on_round: Callable[[int], None] | None = None,
) -> dict:
    """Train `actor` in place; returns {"episodes", "samples", "wall_s", "final_mse"}.
    `on_round(done)` after each round (a progress bar)."""
    scales = FeatureScales.from_mission(mission)
    rng = np.random.default_rng(args.seed)
    opt = torch.optim.Adam(actor.parameters(), lr=args.lr)
    data: dict[str, list[torch.Tensor]] = {k: [] for k in (*INPUTS, "u")}
    t0 = time.time()
    mse = float("nan")
    episodes = 0
    cycle = [int(x) for x in rng.permutation(args.tup_choices)] if args.tup_chunks > 1 else []
    tups: list[int] = []
    for rnd in range(args.rounds):
        beta = 1.0 if rnd == 0 else 0.5 ** rnd
        if args.tup_chunks <= 1:
            batches = [(int(rng.choice(args.tup_choices)), args.episodes_per_round, args.seed + 7 * rnd + 1)]
        else:
            per = max(1, args.episodes_per_round // args.tup_chunks)
            batches = [(cycle[(rnd * args.tup_chunks + c) % len(cycle)], per, args.seed + 7 * rnd + 1 + 1000 * c)
                       for c in range(args.tup_chunks)]
        for tup, n_eps, env_seed in batches:
            tups.append(tup)
            m = trainer_scenario(mission, rng, args).with_tup(tup)
            p_fail = args.failure_prob
            if args.failures == "scripted":
                m, p_fail = scripted_failures(m, rng, args.failure_window_s), 0.0
            env = CoverageEnv(m, n_eps, training_twin_seed(env_seed), failure_prob=p_fail,
                              random_launch=random_launch(m, args.general))
            teacher = GreedyController(env)
            react = ReactTargets.of(m) if args.teacher == "react" else None
            perceive = Perception(tracker, PolicyForm.trained(actor.reads_map), scales.r_comm, m)
            obs = env.reset()
            teacher.reset()
            use_teacher = torch.from_numpy(rng.random(n_eps) < beta).view(-1, 1, 1)
            with torch.no_grad():
                while not env.done:
                    inputs = perceive(obs)
                    x = policy_input(scales, inputs)
                    if react is not None:
                        a_teacher = react.accel(obs.ego, react.update_true(obs))
                    elif args.teacher == "plan":
                        a_teacher = perceive.plan.accel(obs.ego, inputs.target)
                    elif args.teacher == "track":
                        rs = float(m.radii.sensing_m)
                        point = joint_track(inputs.target, obs.ego, obs.sense, obs.alive, radius_m=rs, leash_m=args.track_m,
                                            link_m=LINK_FRAC * float(m.radii.comm_m), apart_m=2.0 * rs,
                                            margin_m=args.track_link_frac * float(m.radii.comm_m))
                        a_teacher = perceive.plan.accel(obs.ego, point)
                    else:
                        a_teacher = teacher.act_from_state(obs)
                    u = torch.clamp(a_teacher / scales.a_max, -0.999, 0.999)
                    live = obs.alive
                    for k, v in zip(INPUTS, x, strict=True):
                        data[k].append(v[live])
                    data["u"].append(u[live])
                    a_student = actor(*x) * scales.a_max
                    obs, _, _ = env.step(torch.where(use_teacher, a_teacher, a_student))
            episodes += n_eps
        ds = {k: torch.cat(v) if k in ("ego", "u") else cat_slots(v) for k, v in data.items()}
        n = ds["u"].shape[0]
        for _ in range(args.epochs):
            perm = torch.randperm(n)
            for lo in range(0, n, args.batch):
                idx = perm[lo : lo + args.batch]
                pred = actor(*(ds[k][idx] for k in INPUTS))
                loss = ((pred - ds["u"][idx]) ** 2).sum(-1).mean()
                opt.zero_grad()
                loss.backward()
                opt.step()
                mse = float(loss.detach())
        log(f"imitation round {rnd}: beta {beta:.2f}, T_up {[b[0] for b in batches]}, {n} samples, mse {mse:.4f} ({time.time() - t0:.0f} s)")
        if on_round is not None:
            on_round(rnd + 1)
    return {"episodes": episodes, "samples": int(ds["u"].shape[0]), "wall_s": time.time() - t0, "final_mse": mse, "tups": tups,
            "args": {k: (list(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(args).items()}}
