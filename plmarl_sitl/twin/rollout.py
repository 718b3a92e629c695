"""Run whole episodes of a controller in the twin: THE rollout loop (`plmarl sim` and
`plmarl eval` both use it), and the `Controller` protocol every controller meets."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import torch

from plmarl_sitl.mission import Mission
from plmarl_sitl.twin.env import CoverageEnv, Observation


class Controller(Protocol):
    """Acts for all (B, N) agents of a twin batch: the Oracle, the heuristic, a learnt policy."""

    def reset(self) -> None:
        """Forget the last episode (called before its first decision)."""

    def act(self, obs: Observation) -> torch.Tensor:
        """(B, N, 3) acceleration commands, m/s^2, mission frame."""


@dataclass(frozen=True)
class Rollout:
    """Per-episode traces of a batch of episodes, one value per physics second t = 1..T."""

    coverage: torch.Tensor  # (E, T) C(t)
    lambda2: torch.Tensor  # (E, T) lambda_2(t)
    min_separation: torch.Tensor  # (E,) smallest live-pair distance seen, metres


@dataclass(frozen=True)
class EpisodeMetrics:
    coverage: np.ndarray  # (E,) mean C(t) over the episode
    lambda2: np.ndarray  # (E,) mean lambda_2 over the episode
    min_separation: np.ndarray  # (E,) smallest live-pair distance, metres
    coverage_trace: np.ndarray  # (E, T) C(t) per second


def rollout_batches(
    mission: Mission,
    make_controller: Callable[[CoverageEnv], Controller],
    episodes: int,
    seed: int,
    *,
    batch: int,
    failure_prob: float = 0.0,
    on_decision: Callable[[int], None] | None = None,
) -> list[Rollout]:
    """`episodes` episodes in batches of at most `batch` parallel environments, one
    `Rollout` per batch. Batch k uses twin seed `seed + k`, so results depend only on
    (seed, episodes, batch), and every controller sees the same episodes.
    `on_decision(n_envs)` is called after every decision (for progress bars)."""
    out = []
    with torch.inference_mode():  # no gradients flow through an evaluation rollout
        for k, lo in enumerate(range(0, episodes, batch)):
            b = min(batch, episodes - lo)
            env = CoverageEnv(mission, b, seed + k, track_lambda2=True, failure_prob=failure_prob)
            ctl = make_controller(env)
            ctl.reset()
            obs = env.observe()
            cs, ls = [], []
            min_sep = torch.full((b,), float("inf"))
            while not env.done:
                obs, _, info = env.step(ctl.act(obs))
                cs.append(info.coverage)
                ls.append(info.lambda2)
                min_sep = torch.minimum(min_sep, info.min_separation)
                if on_decision:
                    on_decision(b)
            out.append(Rollout(torch.cat(cs, -1), torch.cat(ls, -1), min_sep))
    return out


def run_episodes(
    mission: Mission,
    make_controller: Callable[[CoverageEnv], Controller],
    episodes: int,
    seed: int,
    *,
    batch: int = 64,
    on_decision: Callable[[int], None] | None = None,
) -> EpisodeMetrics:
    """Whole-episode metrics of `episodes` episodes (see `rollout_batches`)."""
    runs = rollout_batches(mission, make_controller, episodes, seed, batch=batch, on_decision=on_decision)
    return EpisodeMetrics(
        np.concatenate([r.coverage.mean(-1).numpy() for r in runs]),
        np.concatenate([r.lambda2.mean(-1).numpy() for r in runs]),
        np.concatenate([r.min_separation.numpy() for r in runs]),
        np.concatenate([r.coverage.numpy() for r in runs]),
    )
