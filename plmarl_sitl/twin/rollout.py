"""Run whole episodes of a controller in the twin and collect per-episode metrics."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from plmarl_sitl.mission import Mission
from plmarl_sitl.twin.env import CoverageEnv, Observation


@dataclass(frozen=True)
class EpisodeMetrics:
    coverage: np.ndarray  # (E,) mean C(t) over the episode
    lambda2: np.ndarray  # (E,) mean lambda_2 over the episode
    min_separation: np.ndarray  # (E,) smallest live-pair distance, metres
    coverage_trace: np.ndarray  # (E, T) C(t) per second


def run_episodes(
    mission: Mission,
    make_controller: Callable[[CoverageEnv], object],
    episodes: int,
    seed: int,
    *,
    batch: int = 64,
    on_decision: Callable[[int], None] | None = None,
) -> EpisodeMetrics:
    """Run `episodes` episodes in batches of at most `batch` parallel environments.

    Batch k uses seed `seed + k`, so results depend only on (seed, episodes, batch).
    `on_decision(n_envs)` is called after every decision (for progress bars).
    """
    with torch.inference_mode():  # no gradients flow through an evaluation rollout
        return _run(mission, make_controller, episodes, seed, batch, on_decision)


def _run(mission, make_controller, episodes, seed, batch, on_decision) -> EpisodeMetrics:  # noqa: ANN001
    cov, lam, sep, traces = [], [], [], []
    for k, lo in enumerate(range(0, episodes, batch)):
        b = min(batch, episodes - lo)
        env = CoverageEnv(mission, b, seed + k, track_lambda2=True)
        ctl = make_controller(env)
        obs: Observation = env.observe()
        ctl.reset()
        c_steps, l_steps = [], []
        min_sep = torch.full((b,), float("inf"))
        while not env.done:
            obs, _, info = env.step(ctl.act(obs))
            c_steps.append(info.coverage)
            l_steps.append(info.lambda2)
            min_sep = torch.minimum(min_sep, info.min_separation)
            if on_decision:
                on_decision(b)
        trace = torch.cat(c_steps, -1)
        traces.append(trace.numpy())
        cov.append(trace.mean(-1).numpy())
        lam.append(torch.cat(l_steps, -1).mean(-1).numpy())
        sep.append(min_sep.numpy())
    return EpisodeMetrics(np.concatenate(cov), np.concatenate(lam), np.concatenate(sep), np.concatenate(traces))
