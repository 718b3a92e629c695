"""Twin seeds: training and the held-out evaluation suite draw from disjoint ranges.

One integer seeds a `CoverageEnv`; it fixes everything random in its episodes: random
cluster layouts, users' start and motion, mixed-mobility kinds and random node failures.
So "held out" means "seeded from a range training never uses":

* training (engine data, imitation, MAPPO rollouts) seeds every twin it builds
  through `training_twin_seed`, which refuses seeds at or above EVAL_SEED_BASE;
* the suite (`plmarl suite`) seeds every twin through `suite_twin_seed`, which only
  returns seeds at or above EVAL_SEED_BASE.

Today's training seeds stay far below the bound: `plmarl train --seed s` builds twins with
s + small offsets (engine data, imitation) and s * 100_003 + iteration (MAPPO), so any
training seed below about 9_999 is accepted; a larger one fails loudly instead of
silently drawing evaluation episodes.
"""

from __future__ import annotations

from plmarl_sitl.errors import UserError

EVAL_SEED_BASE = 1_000_000_000
SUITE_RUN_STRIDE = 10_000  # suite seeds of run --seed S start at EVAL_SEED_BASE + S * stride
SUITE_VARIANT_STRIDE = 100  # ... and of mission variant v at + v * stride; batch k adds k
SUITE_MAX_RUN_SEED = 99_999


def training_twin_seed(seed: int) -> int:
    """`seed` if a training twin may use it; UserError if it lies in the evaluation range."""
    if not 0 <= seed < EVAL_SEED_BASE:
        raise UserError(
            f"training twin seed {seed} is outside [0, {EVAL_SEED_BASE}): seeds from {EVAL_SEED_BASE} up are "
            "reserved for the held-out evaluation suite (use a smaller --seed)"
        )
    return seed


def suite_twin_seed(run_seed: int, variant: int, batch: int = 0) -> int:
    """The twin seed of batch `batch` of mission variant `variant` in suite run `run_seed`."""
    if not 0 <= run_seed <= SUITE_MAX_RUN_SEED:
        raise UserError(f"suite --seed must be in 0..{SUITE_MAX_RUN_SEED}, got {run_seed}")
    if not 0 <= variant < SUITE_RUN_STRIDE // SUITE_VARIANT_STRIDE:
        raise UserError(f"a suite family may list at most {SUITE_RUN_STRIDE // SUITE_VARIANT_STRIDE} missions")
    if not 0 <= batch < SUITE_VARIANT_STRIDE:
        raise UserError(f"too many episodes: a mission variant may use at most {SUITE_VARIANT_STRIDE} twin batches")
    seed = EVAL_SEED_BASE + run_seed * SUITE_RUN_STRIDE + variant * SUITE_VARIANT_STRIDE + batch
    assert seed >= EVAL_SEED_BASE  # the whole point: never a training seed
    return seed
