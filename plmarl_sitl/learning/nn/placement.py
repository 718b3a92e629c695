"""The learnt placement scorer (issue 24.3): a small MLP that ranks the candidate points a
team plan's greedy may pick next (model/placement.py `LearnedPlacement`, features
`PickState.features`). Exported as TorchScript in float64 so every agent's copy of the plan
scores alike; trained by learning/train/placement.py."""

from __future__ import annotations

from pathlib import Path

import torch
from torch import nn

from plmarl_sitl.errors import UserError
from plmarl_sitl.model.placement import FEATURES


class PlacementScorer(nn.Module):
    """(k, FEATURES) candidate features -> (k,) scores (higher: pick)."""

    def __init__(self, hidden: int = 32) -> None:
        super().__init__()
        self.net = nn.Sequential(nn.Linear(FEATURES, hidden), nn.Tanh(), nn.Linear(hidden, hidden), nn.Tanh(),
                                 nn.Linear(hidden, 1))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x).squeeze(-1)


def export(model: PlacementScorer, path: Path) -> None:
    """Save as float64 TorchScript."""
    torch.jit.save(torch.jit.script(model.double().eval()), str(path))


def load_placement_scorer(path: Path) -> torch.jit.ScriptModule:
    """The scorer file; a one-line error if it is missing or not a scorer."""
    if not Path(path).is_file():
        raise UserError(f"placement: learned needs the scorer {path} (plmarl train's placement step writes it)")
    try:
        return torch.jit.load(str(path), map_location="cpu").eval()
    except RuntimeError as e:
        raise UserError(f"{path}: not a TorchScript placement scorer ({str(e).splitlines()[0]})") from None
