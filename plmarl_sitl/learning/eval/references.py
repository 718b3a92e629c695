"""The references every fraction is taken against, and the best of them per episode.

A reference is a method the others are measured against. None of them is a proven bound:
a reference a method beats is not a ceiling, so every report says which one it used.

* greedy      greedy clairvoyant placement (twin/greedy.py; "the Oracle" before issue 24):
              global knowledge, one sequential greedy plan, replaced only when another
              greedy plan covers more users;
* clairvoyant re-chooses every decision, with true states and users, the best of several
              plans (its current one, the greedy's, fresh greedy plans from several first
              points and the service plan on the true users, each improved locally) by a
              flown look-ahead (twin/clairvoyant.py);
* service     the plan follower: no learning, only what a deployed agent has (the launch
              line at t = 0 and the published demand maps; learning/eval/controllers.py).

The best reference of an episode is the reference with the highest steady-state coverage
on that episode, among those the run included; a method's fraction is its coverage over
that one's on the same episode (so it is <= 1 for every reference itself, and a method
that ties one reference but loses to another on some episodes gets less than 1). A
failure transient is measured against the trace of the same per-episode best reference.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass

import numpy as np

REFERENCES = ("clairvoyant", "greedy", "service")  # on an exact tie the earlier one is named
ABOUT = {
    "greedy": "greedy clairvoyant placement (global knowledge, one greedy plan kept until a greedy plan covers more; "
              "'the Oracle' before issue 24)",
    "clairvoyant": "clairvoyant re-plan every decision with true states and users, best of several plans by a flown "
                   "look-ahead",
    "service": "the plan follower (no learning; launch line and published maps only)",
}


@dataclass(frozen=True)
class BestReference:
    coverage: np.ndarray  # (E,) steady-state coverage of the best reference, per episode
    trace: np.ndarray  # (E, T) that reference's C(t)
    which: np.ndarray  # (E,) its name

    def label(self) -> str:
        """'clairvoyant 7/10, service 3/10': which reference was best, how often."""
        counts = Counter(self.which.tolist())
        order = sorted(counts, key=lambda k: (-counts[k], REFERENCES.index(k)))
        return ", ".join(f"{k} {counts[k]}/{self.which.size}" for k in order)

    def shares(self) -> dict[str, float]:
        counts = Counter(self.which.tolist())
        return {k: counts[k] / self.which.size for k in REFERENCES if k in counts}


def best_reference(runs: dict[str, tuple[np.ndarray, np.ndarray]]) -> BestReference | None:
    """runs: {method: (coverage (E,), trace (E, T))} of one sweep point; None without a reference."""
    refs = [r for r in REFERENCES if r in runs]
    if not refs:
        return None
    cov = np.stack([runs[r][0] for r in refs])  # (R, E)
    k = cov.argmax(0)  # first maximum: REFERENCES order on ties
    e = np.arange(cov.shape[1])
    traces = np.stack([runs[r][1] for r in refs])
    return BestReference(cov[k, e], traces[k, e], np.array(refs)[k])


def pairwise_wins(coverage: dict[str, np.ndarray]) -> dict[str, float]:
    """{'clairvoyant>greedy': share of episodes where the first covers more, ...} for every
    ordered pair of the references present (coverage: {method: (E,)})."""
    refs = [r for r in REFERENCES if r in coverage]
    return {f"{a}>{b}": float(np.mean(coverage[a] > coverage[b])) for a in refs for b in refs if a != b}
