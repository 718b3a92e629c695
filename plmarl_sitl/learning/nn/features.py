"""The ONE function that turns what an agent knows (`contract.PolicyInputs`) into the
actor's input tensors.

Both the digital-twin trainer (`policy_input`) and the deployed agent call
`build_policy_input` (it is compiled into `policy.pt`, so a deployed agent that calls the
exported policy on raw physical tensors runs exactly this code). Everything here is
TorchScript-compatible.

Inputs (the fields of `PolicyInputs`) are physical, in the mission frame (metres from the
area's SW corner, x north, y east, z down; m/s), see docs/POLICY_IO.md (input version 2):

* ego (..., 6): own true [p_n, p_e, p_d, v_n, v_e, v_d]
* beliefs (..., M, 6): the belief tracker's reconstructed neighbour states, same frame
* mask (..., M) bool: neighbour j is in N_i (heard recently enough and alive)
* sense (..., SENSING_FEATURES = 4): `plmarl_sitl.model.coverage.sensing_features` of the agent
* fail (...) bool: the agent's failure state f (`plmarl_sitl.model.signalling.silent_in_range`, latched)
* demand (..., K, 3) or None: the published user-density map, [cell centre north, east, user
  count] (`plmarl_sitl.model.demand`); any K, empty or padding cells with count 0 add
  nothing; None (no map yet) is an empty map
* target (..., 2) or None: the agent's point of the team plan (`plmarl_sitl.model.service`),
  north and east in the mission frame; None: no plan yet

Nothing the policy sees is an absolute horizontal position, so it cannot memorise sites,
and no size depends on N, on the number of clusters or on the area (issue 12):

* ego: altitude 0..alt_max -> [-1, 1], velocity / V_max, sensing, f, and the demand
  descriptor: the map's cells binned into DEMAND_SECTORS sectors (by the signs and the
  larger of the north/east offsets: octants, no trigonometry) x len(DEMAND_RING_EDGES_M) + 1
  range rings around the agent, once for all users and once for the users not claimed by
  a neighbour (cells within `claim_m` of a neighbour's BELIEVED position, i.e. the
  predictor's output), each bin log1p(count / demand_unit);
* neighbours (Encoder input): relative position / R_comm and relative velocity / V_max;
* PE input: relative displacement p_hat_j - p_i / R_comm;
* plan (in ego): the offset to the agent's plan point / R_comm, the same / PLAN_NEAR_M clamped
  to +-1 (fine near the point), and whether a plan is known.
"""

from __future__ import annotations

from typing import NamedTuple

import torch

from plmarl_sitl.learning.nn.contract import PolicyInputs
from plmarl_sitl.model.coverage import SENSING_FEATURES

STATE_DIM = 6
DEMAND_SECTORS = 8
DEMAND_RING_EDGES_M = (100.0, 300.0, 600.0)  # rings: < 100 m (own cell), 100-300, 300-600, beyond
DEMAND_BINS = DEMAND_SECTORS * (len(DEMAND_RING_EDGES_M) + 1)
DEMAND_FEATURES = 2 * DEMAND_BINS  # all users, unclaimed users
PLAN_FEATURES = 5  # the offset to the agent's team-plan point: / R_comm, / PLAN_NEAR_M clamped to +-1, known
PLAN_NEAR_M = 50.0
EGO_FEATURES = 4 + SENSING_FEATURES + 1 + DEMAND_FEATURES + PLAN_FEATURES  # altitude, velocity, sensing, f, demand, plan
NBR_FEATURES = 6  # relative belief state (Encoder input)
TOKEN_FEATURES = 5  # one demand cell as an attention token (demand_tokens)
REL_FEATURES = 3  # relative displacement / R_comm (PE input)


class FeatureScales(NamedTuple):
    alt_max: float
    v_max: float
    a_max: float
    r_comm: float
    claim_m: float  # a cell is claimed by a neighbour believed within this ground distance (R_s)
    demand_unit: float  # users per unit of the demand descriptor (the cluster size)

    @classmethod
    def from_mission(cls, mission) -> FeatureScales:  # noqa: ANN001 - avoid an import cycle
        vm = mission.vehicle_model()
        return cls(
            float(vm.max_alt_m),
            float(vm.max_speed_mps),
            float(vm.max_accel_mps2),
            float(mission.radii.comm_m),
            float(mission.radii.sensing_m),
            float(mission.users.cluster_size),
        )


def map_blind_columns() -> torch.Tensor:
    """The ego features a map-blind actor reads: all but the demand descriptor (altitude,
    velocity, sensing, f, plan)."""
    desc = 4 + SENSING_FEATURES + 1
    return torch.cat([torch.arange(desc), torch.arange(desc + DEMAND_FEATURES, EGO_FEATURES)])


def ring_edges_sq() -> torch.Tensor:
    return torch.tensor([r * r for r in DEMAND_RING_EDGES_M])


def demand_descriptor(
    ego_pos: torch.Tensor,
    demand: torch.Tensor,
    nbr_pos: torch.Tensor,
    mask: torch.Tensor,
    claim_m: float,
    demand_unit: float,
    edges_sq: torch.Tensor,
) -> torch.Tensor:
    """(..., DEMAND_FEATURES): ego_pos (..., 3), demand (..., K, 3), nbr_pos (..., M, 3), mask (..., M)."""
    dn = demand[..., 0] - ego_pos[..., 0:1]
    de = demand[..., 1] - ego_pos[..., 1:2]
    count = demand[..., 2]
    ring = torch.bucketize(dn * dn + de * de, edges_sq.to(dn.dtype))
    sector = (dn < 0).long() * 4 + (de < 0).long() * 2 + (dn.abs() < de.abs()).long()  # 8 octants = DEMAND_SECTORS
    n_bins = 8 * (edges_sq.numel() + 1)  # DEMAND_BINS (TorchScript cannot read module constants)
    bins = ring * 8 + sector
    cn = demand[..., :, None, 0] - nbr_pos[..., None, :, 0]  # (..., K, M)
    ce = demand[..., :, None, 1] - nbr_pos[..., None, :, 1]
    claimed = ((cn * cn + ce * ce <= claim_m * claim_m) & mask.unsqueeze(-2)).any(-1)
    free = torch.where(claimed, torch.zeros_like(count), count)
    out = torch.zeros(bins.shape[:-1] + (2 * n_bins,), dtype=count.dtype, device=count.device)
    out.scatter_add_(-1, bins, count)
    out.scatter_add_(-1, bins + n_bins, free)
    return torch.log1p(out / demand_unit)


def demand_tokens(
    ego_pos: torch.Tensor,
    demand: torch.Tensor,
    nbr_pos: torch.Tensor,
    mask: torch.Tensor,
    r_comm: float,
    demand_unit: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Every demand cell as a token for the policy's demand attention.

    -> (tokens (..., K, TOKEN_FEATURES), token_mask (..., K) = count > 0). A token is
    [north offset / R_comm, east offset / R_comm, log1p(count / demand_unit), the ground
    distance of the nearest believed neighbour minus the agent's own / R_comm (clamped to
    +-2; +2 without neighbours), log1p(believed neighbours nearer the cell than the agent)].
    The last two are what a decentralised assignment needs: which cells are "mine" (no
    one is nearer) and how contested the others are. The octant descriptor loses the
    direction to a cluster to within 45 degrees; a token keeps it exactly.
    """
    dn = demand[..., 0] - ego_pos[..., 0:1]
    de = demand[..., 1] - ego_pos[..., 1:2]
    count = demand[..., 2]
    own = torch.sqrt(dn * dn + de * de)
    cn = demand[..., :, None, 0] - nbr_pos[..., None, :, 0]  # (..., K, M)
    ce = demand[..., :, None, 1] - nbr_pos[..., None, :, 1]
    theirs = torch.sqrt(cn * cn + ce * ce)
    live = mask.unsqueeze(-2)
    far = torch.full_like(theirs, 4.0 * r_comm)
    nearest = torch.where(live, theirs, far).min(-1).values if theirs.shape[-1] > 0 else far.sum(-1)
    nearer = ((theirs < own.unsqueeze(-1)) & live).sum(-1).to(count.dtype)
    advantage = torch.clamp((nearest - own) / r_comm, -2.0, 2.0)
    tokens = torch.stack([dn / r_comm, de / r_comm, torch.log1p(count / demand_unit), advantage, torch.log1p(nearer)], -1)
    return tokens, count > 0


def build_policy_input(
    x: PolicyInputs,
    alt_max: float,
    v_max: float,
    r_comm: float,
    claim_m: float,
    demand_unit: float,
    edges_sq: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """-> (ego_x (..., EGO_FEATURES), nbr_x (..., M, 6), rel_x (..., M, 3), mask (..., M) bool,
    tok_x (..., K, TOKEN_FEATURES), tok_mask (..., K) bool).

    `x.demand` (..., K, 3) has ego's leading shape (expand one map over the agents of an
    environment). Neighbour slots outside the mask are ignored by the attention and by the
    claims, so they may hold any FINITE values.
    """
    ego, beliefs, mask = x.ego, x.beliefs, x.mask
    demand = x.demand
    if demand is None:  # no map received yet: no demand known beyond the own sensing
        demand = torch.zeros(ego.shape[:-1] + (1, 3), dtype=ego.dtype, device=ego.device)
    target = x.target
    known = torch.full(ego.shape[:-1], target is not None, dtype=torch.bool, device=ego.device)
    if target is None:  # no plan yet (no map yet): the plan features are 0
        target = torch.zeros(ego.shape[:-1] + (2,), dtype=ego.dtype, device=ego.device)
    alt = ego[..., 2:3] * (-2.0 / alt_max) - 1.0
    desc = demand_descriptor(ego[..., 0:3], demand, beliefs[..., 0:3], mask, claim_m, demand_unit, edges_sq)
    known_x = known.unsqueeze(-1).to(ego.dtype)
    off = (target - ego[..., 0:2]) * known_x
    plan = torch.cat([off / r_comm, torch.clamp(off / 50.0, -1.0, 1.0), known_x], -1)  # 50 m = PLAN_NEAR_M
    ego_x = torch.cat([alt, ego[..., 3:6] / v_max, x.sense, x.fail.unsqueeze(-1).to(ego.dtype), desc, plan], -1)
    rel_x = (beliefs[..., 0:3] - ego[..., 0:3].unsqueeze(-2)) / r_comm
    nbr_x = torch.cat([rel_x, (beliefs[..., 3:6] - ego[..., 3:6].unsqueeze(-2)) / v_max], -1)
    tok_x, tok_mask = demand_tokens(ego[..., 0:3], demand, beliefs[..., 0:3], mask, r_comm, demand_unit)
    return ego_x, nbr_x, rel_x, mask, tok_x, tok_mask


def policy_input(
    scales: FeatureScales, x: PolicyInputs
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """`build_policy_input` with a mission's constants: the trainers' form (the actor's inputs)."""
    s = scales
    return build_policy_input(x, s.alt_max, s.v_max, s.r_comm, s.claim_m, s.demand_unit, ring_edges_sq())
