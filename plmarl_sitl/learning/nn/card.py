"""The schema of a policy's card.yaml, checked as strictly as a mission.

Why: the card says what the two TorchScript files are (method, input contract, the
normalisation scales, their sha256). A card with `method: 123`, an unknown key or
`obs_dim: 'many'` used to load and fly; every key is now known and typed, and an error
names its path the way a mission error does (`io.buffer_len: expected an integer`).
The free-form records of how the policy was made (training curves, imitation, config,
evaluation, notes) stay free-form.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any

from plmarl_sitl.config import MAX_SEED, ConfigError, from_dict

POLICY_FILES = ("predictor.pt", "policy.pt")
_SHA256 = re.compile(r"[0-9a-f]{64}")


@dataclass(frozen=True)
class CardIO:
    """The policy files' input contract (docs/POLICY_IO.md)."""

    state_dim: int = field(metadata={"min": 1})
    sense_dim: int = field(metadata={"min": 0})
    ego_features: int = field(metadata={"min": 1})
    buffer_len: int = field(metadata={"min": 1})
    dt_s: float = field(metadata={"min": 1e-6})
    scales: Any = None
    input_version: int = field(default=1, metadata={"min": 1, "max": 2})
    takes_plan: bool = False
    reads_map: bool | None = None
    demand_cell_fields: int | None = field(default=None, metadata={"min": 1})

    def __post_init__(self) -> None:
        if not isinstance(self.scales, dict) or not self.scales:
            raise ConfigError("scales", "expected a mapping of scale name -> number")
        for k, v in self.scales.items():
            if not isinstance(k, str) or isinstance(v, bool) or not isinstance(v, (int, float)):
                raise ConfigError(f"scales.{k}", "expected a number")


@dataclass(frozen=True)
class PolicyCard:
    method: str
    card_version: int
    io: CardIO
    sha256: Any
    mission: str = ""
    seed: int = field(default=0, metadata={"min": 0, "max": MAX_SEED})
    git_commit: str = ""
    note: str = ""
    learnt: bool = True  # False: a policy file that is not learnt (policies/service, the plan follower)
    mission_file: str = ""  # the mission file it was made from (policies/service)
    cruise_alt_m: float | None = field(default=None, metadata={"min": 0.0})  # a fixed flying altitude (policies/service)
    # The swarm sizes [lo, hi] and the vehicle model it was trained with (cards from issue 26 on).
    trained_on: Any = None
    # Free-form records of how the policy was made.
    config: Any = None
    training: Any = None
    imitation: Any = None
    eval: Any = None
    predictor: Any = None
    export: Any = None  # how the files were (re-)exported (learning/nn/convert.py)

    def __post_init__(self) -> None:
        if not self.method.strip():
            raise ConfigError("method", "must name the method")
        if not isinstance(self.sha256, dict):
            raise ConfigError("sha256", f"expected a mapping of {' and '.join(POLICY_FILES)} -> sha256")
        for k, v in self.sha256.items():
            if k not in POLICY_FILES:
                raise ConfigError(f"sha256.{k}", f"unknown file (allowed: {', '.join(POLICY_FILES)})")
            if not isinstance(v, str) or not _SHA256.fullmatch(v):
                raise ConfigError(f"sha256.{k}", "expected 64 lowercase hex digits")


def trained_n_range(card: dict) -> tuple[int, int] | None:
    """The swarm sizes the policy was trained on, [lo, hi], if its card records them (the
    training distribution's `n_uavs`, or the mission's N for a single-mission policy)."""
    trained_on = card.get("trained_on")
    dist = (card.get("training") or {}).get("distribution") if isinstance(card.get("training"), dict) else None
    if isinstance(trained_on, dict):
        n = trained_on.get("n_uavs")
    else:
        n = dist.get("n_uavs") if isinstance(dist, dict) else card.get("n_uavs")
    if isinstance(n, int) and not isinstance(n, bool):
        return n, n
    if isinstance(n, list) and len(n) == 2 and all(isinstance(x, int) for x in n):
        return int(n[0]), int(n[1])
    return None


def swarm_size_warning(card: dict, n_uavs: int) -> str | None:
    """A line for a user flying the policy at a swarm size it never saw in training, or None."""
    trained = trained_n_range(card)
    if trained is None or trained[0] <= n_uavs <= trained[1]:
        return None
    seen = f"N = {trained[0]}" if trained[0] == trained[1] else f"N = {trained[0]}..{trained[1]}"
    return (f"policy {card.get('method', '?')} was trained at {seen}; this mission flies N = {n_uavs} "
            "(zero-shot: see docs/RESULTS.md for how it generalises)")


def check_card(data: Any) -> PolicyCard:
    """The typed card of a card.yaml's plain data; ConfigError naming the key path."""
    return from_dict(PolicyCard, data)
