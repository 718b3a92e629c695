"""Run whole episodes of a controller in the twin: the one rollout loop.

`rollout` steps batches of episodes and keeps per-second traces; `run_episodes` (for
`plmarl sim`) and the evaluation sweeps (`learning.eval.evaluate`) reduce those traces
their own way. Every controller, hand-written (greedy, clairvoyant, heuristic) or learnt, is a
`Controller`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import torch

from plmarl_sitl.mission import Mission
from plmarl_sitl.twin.env import CoverageEnv, Observation


class Controller(Protocol):
    """Drives the whole swarm of a batch of twin episodes, one decision at a time."""

    def reset(self) -> None:
        """Forget everything: a new batch of episodes starts."""

    def act(self, obs: Observation) -> torch.Tensor:
        """(B, N, 3) net acceleration commands for the observation of every UAV."""


MakeController = Callable[[CoverageEnv], Controller]


@dataclass(frozen=True)
class BatchTrace:
    """One batch of episodes, second by second."""

    coverage: torch.Tensor  # (b, T) C(t) after second t = 1..T
    lambda2: torch.Tensor  # (b, T) lambda_2 after second t
    min_separation: torch.Tensor  # (b,) smallest live-pair distance over the episode, metres


def rollout(
    mission: Mission,
    make_controller: MakeController,
    episodes: int,
    seed: int,
    *,
    batch: int,
    failure_prob: float = 0.0,
    on_decision: Callable[[int], None] | None = None,
) -> list[BatchTrace]:
    """Run `episodes` episodes in batches of at most `batch` parallel environments.

    Batch k uses twin seed `seed + k`, so results depend only on (seed, episodes, batch),
    and every controller sees the same episodes. `on_decision(n_envs)` is called after
    every decision (for progress bars).
    """
    out = []
    with torch.inference_mode():  # no gradients flow through an evaluation rollout
        for k, lo in enumerate(range(0, episodes, batch)):
            b = min(batch, episodes - lo)
            env = CoverageEnv(mission, b, seed + k, track_lambda2=True, failure_prob=failure_prob)
            ctl = make_controller(env)
            ctl.reset()
            obs = env.observe()
            c_steps, l_steps = [], []
            min_sep = torch.full((b,), float("inf"))
            while not env.done:
                obs, _, info = env.step(ctl.act(obs))
                c_steps.append(info.coverage)
                l_steps.append(info.lambda2)
                min_sep = torch.minimum(min_sep, info.min_separation)
                if on_decision:
                    on_decision(b)
            out.append(BatchTrace(torch.cat(c_steps, -1), torch.cat(l_steps, -1), min_sep))
    return out


@dataclass(frozen=True)
class EpisodeMetrics:
    coverage: np.ndarray  # (E,) mean C(t) over the episode
    lambda2: np.ndarray  # (E,) mean lambda_2 over the episode
    min_separation: np.ndarray  # (E,) smallest live-pair distance, metres
    coverage_trace: np.ndarray  # (E, T) C(t) per second


def run_episodes(
    mission: Mission,
    make_controller: MakeController,
    episodes: int,
    seed: int,
    *,
    batch: int = 64,
    on_decision: Callable[[int], None] | None = None,
) -> EpisodeMetrics:
    """Whole-episode means of `episodes` episodes (see `rollout`)."""
    runs = rollout(mission, make_controller, episodes, seed, batch=batch, on_decision=on_decision)
    return EpisodeMetrics(
        np.concatenate([r.coverage.mean(-1).numpy() for r in runs]),
        np.concatenate([r.lambda2.mean(-1).numpy() for r in runs]),
        np.concatenate([r.min_separation.numpy() for r in runs]),
        np.concatenate([r.coverage.numpy() for r in runs]),
    )
