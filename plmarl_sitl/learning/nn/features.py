"""The ONE function that turns what an agent knows into the policy's input tensors.

Both the digital-twin trainer and the deployed agent call `build_policy_input` (it is also
compiled into `policy.pt`, so a deployed agent that calls the exported policy on raw
physical tensors runs exactly this code). Everything here is TorchScript-compatible.

Inputs are physical, in the mission frame (metres from the area's SW corner, x north,
y east, z down; m/s), see docs/POLICY_IO.md:

* ego (..., 6): own true [p_n, p_e, p_d, v_n, v_e, v_d]
* beliefs (..., M, 6): the belief tracker's reconstructed neighbour states, same frame
* mask (..., M) bool: neighbour j is in N_i (heard recently enough and alive)
* sense (..., SENSING_FEATURES = 4): `plmarl_sitl.model.coverage.sensing_features` of the agent
* fail_flag (...) bool: the agent's local failure state f

Normalisation (constants in `FeatureScales`, stored in the exported policy):
ego position -> [-1, 1] over the area and altitude band, velocity / V_max; neighbour
belief likewise (Encoder input); relative displacement (belief - ego position) / R_comm
(the PE input, translation invariant).
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from plmarl_sitl.model.coverage import SENSING_FEATURES

STATE_DIM = 6
EGO_FEATURES = 6 + SENSING_FEATURES + 1  # normalised state, sensing, failure flag
NBR_FEATURES = 6  # normalised belief state (Encoder input)
REL_FEATURES = 3  # relative displacement / R_comm (PE input)


class FeatureScales(NamedTuple):
    area_n: float
    area_e: float
    alt_max: float
    v_max: float
    a_max: float
    r_comm: float

    @classmethod
    def from_mission(cls, mission) -> FeatureScales:  # noqa: ANN001 - avoid an import cycle
        vm = mission.vehicle_model()
        return cls(
            float(mission.area.north_m),
            float(mission.area.east_m),
            float(vm.max_alt_m),
            float(vm.max_speed_mps),
            float(vm.max_accel_mps2),
            float(mission.radii.comm_m),
        )

    def norm(self) -> torch.Tensor:
        return state_norm(self.area_n, self.area_e, self.alt_max, self.v_max)


def state_norm(area_n: float, area_e: float, alt_max: float, v_max: float) -> torch.Tensor:
    """(2, 6) [scale; offset] so that normalised = s * scale + offset: north/east over the
    area -> [-1, 1], altitude (= -p_d) 0..alt_max -> [-1, 1], velocity / v_max."""
    scale = torch.tensor([2.0 / area_n, 2.0 / area_e, -2.0 / alt_max, 1.0 / v_max, 1.0 / v_max, 1.0 / v_max])
    offset = torch.tensor([-1.0, -1.0, -1.0, 0.0, 0.0, 0.0])
    return torch.stack([scale, offset])


def build_policy_input(
    ego: torch.Tensor,
    beliefs: torch.Tensor,
    mask: torch.Tensor,
    sense: torch.Tensor,
    fail_flag: torch.Tensor,
    norm: torch.Tensor,
    inv_r_comm: float,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """-> (ego_x (..., EGO_FEATURES), nbr_x (..., M, 6), rel_x (..., M, 3), mask (..., M) bool).

    `norm` is `state_norm(...)` (or `FeatureScales.norm()`), `inv_r_comm` = 1 / R_comm. Neighbour slots outside the
    mask are ignored by the attention (their weight is exactly 0), so they may hold any
    FINITE values (a failed neighbour's stale state, zeros for a never-heard slot).
    """
    scale, offset = norm[0], norm[1]
    ego_x = torch.cat([torch.addcmul(offset, ego, scale), sense, fail_flag.unsqueeze(-1).to(ego.dtype)], -1)
    nbr_x = torch.addcmul(offset, beliefs, scale)
    rel_x = (beliefs[..., 0:3] - ego[..., 0:3].unsqueeze(-2)) * inv_r_comm
    return ego_x, nbr_x, rel_x, mask
