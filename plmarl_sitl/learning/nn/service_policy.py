"""`policies/service/`: the plan follower `service` as a policy file, so SITL can fly it.

Not learnt. The deployed agent already computes its point of the team plan (model/service.py,
deploy/agent/plan.py) and hands it to a policy that takes the plan as its 7th input
(docs/POLICY_IO.md). This module is such a policy with no weights: it flies to that point at
the altitude of the largest coverage radius and stops there, exactly what the twin's
`ServiceController` does (`ServiceTargets.accel`; tests/learning/test_service_policy.py checks
the two fly the same episodes). Its tracker is the hold tracker (beliefs = held states); the
plan follower reads no belief.

The altitude is the mission's (its channel and vehicle band): the file is exported for one
mission, and its card says which. Regenerate with

    python -m plmarl_sitl.learning.nn.service_policy --mission missions/paper_urban.yaml --out policies/service
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Optional

import torch
from torch import nn

from plmarl_sitl.learning.nn.belief import BeliefTracker
from plmarl_sitl.learning.nn.contract import INPUT_VERSION
from plmarl_sitl.learning.nn.features import FeatureScales
from plmarl_sitl.learning.nn.predictor import make_predictor
from plmarl_sitl.model.channel import mission_coverage
from plmarl_sitl.model.vehicle import goto_accel


class ServicePolicy(nn.Module):
    """forward(ego, beliefs, mask, sense, fail_flag, demand, target) -> the acceleration that flies
    to target (..., 2) at `cruise_alt` and stops there; before the first plan (target None) it
    brakes where it is."""

    def __init__(self, scales: FeatureScales, cruise_alt_m: float, time_const_s: float) -> None:
        super().__init__()
        self.alt_max, self.v_max, self.a_max, self.r_comm = scales.alt_max, scales.v_max, scales.a_max, scales.r_comm
        self.claim_m, self.demand_unit = scales.claim_m, scales.demand_unit
        self.input_version = INPUT_VERSION
        self.takes_plan = True
        self.reads_map = False  # the map reaches it only through the plan's target
        self.cruise_alt = float(cruise_alt_m)
        self.time_const = float(time_const_s)

    def forward(
        self,
        ego: torch.Tensor,
        beliefs: torch.Tensor,
        mask: torch.Tensor,
        sense: torch.Tensor,
        fail_flag: torch.Tensor,
        demand: Optional[torch.Tensor] = None,  # noqa: UP045 - TorchScript needs Optional
        target: Optional[torch.Tensor] = None,  # noqa: UP045
    ) -> torch.Tensor:
        xy = ego[..., :2] if target is None else target
        goal = torch.cat([xy, torch.full_like(xy[..., :1], -self.cruise_alt)], -1)
        return goto_accel(ego[..., :3], ego[..., 3:], goal, self.v_max, self.a_max, time_const=self.time_const)


def service_policy(mission) -> ServicePolicy:  # noqa: ANN001 - Mission
    alt, _ = mission_coverage(mission)
    return ServicePolicy(FeatureScales.from_mission(mission), alt, float(mission.timing.decision_every_s))


def export_service_policy(mission, out_dir: str | Path, mission_path: str = "") -> Path:  # noqa: ANN001 - Mission
    """Write predictor.pt (hold tracker), policy.pt (`ServicePolicy`) and a card saying it is not learnt."""
    from plmarl_sitl.learning.nn.io import export_policy

    policy = service_policy(mission)
    tracker = BeliefTracker(make_predictor("hold", mission.signalling.buffer_len, float(mission.timing.dt_s)),
                            mission.signalling.buffer_len, float(mission.timing.dt_s))
    card = {
        "method": "service",
        "learnt": False,
        "mission": mission.name,
        "mission_file": mission_path,
        "cruise_alt_m": policy.cruise_alt,
        "note": "NOT LEARNT: the plan follower `service` as a policy file. It flies to the agent's point of the team "
                "plan (model/service.py; the agent computes it and passes it as the 7th input) at the altitude of the "
                f"largest coverage radius of mission {mission.name!r} ({policy.cruise_alt:g} m) and stops there; the "
                "tracker holds the received states (no predictor). Exported by "
                "`python -m plmarl_sitl.learning.nn.service_policy` (no training, no seed).",
    }
    return export_policy(out_dir, tracker, policy, card)


def main(argv: list[str] | None = None) -> int:
    from plmarl_sitl.config import PAPER_MISSION
    from plmarl_sitl.mission import load_mission

    p = argparse.ArgumentParser(description="export the plan follower `service` as a policy directory")
    p.add_argument("--mission", default=str(PAPER_MISSION), help="mission YAML (default: the paper's)")
    p.add_argument("--out", default="policies/service", help="policy directory to write (default: policies/service)")
    args = p.parse_args(argv)
    mission = load_mission(args.mission)
    out = export_service_policy(mission, args.out, Path(args.mission).name)
    print(f"wrote {out} (service, not learnt, mission {mission.name})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
