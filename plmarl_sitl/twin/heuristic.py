"""A decentralised hand-written controller: the non-learned baseline below the references.

Each UAV uses only what a deployed agent has (its own state, held neighbour states,
its own user sensing):
* users sensed: fly to the centroid of the users it senses (hill-climbs user density),
  unless a lower-numbered neighbour is within R_s: then it yields and explores, so two
  UAVs do not settle on one cluster;
* none sensed: explore, away from the neighbours it knows of (spreads the swarm);
* keep separation (repulsion within 3 d_safe) and connectivity (pull toward the nearest
  known neighbour when it is beyond 0.8 R_comm);
* hold the altitude with the largest coverage radius.
"""

from __future__ import annotations

import torch

from plmarl_sitl.mission import Mission
from plmarl_sitl.model.channel import mission_coverage
from plmarl_sitl.model.vehicle import velocity_tracking_accel
from plmarl_sitl.twin.env import Observation

EXPLORE_SPEED = 8.0  # m/s
DR_HORIZON_S = 15.0
SEEK_GAIN = 0.15  # 1/s: speed toward the sensed centroid per metre of offset


class HeuristicController:
    def __init__(self, mission: Mission) -> None:
        self.mission = mission
        vm = mission.vehicle_model()
        self.vm = vm
        self.alt, _ = mission_coverage(mission)

    def reset(self) -> None:
        pass

    def act(self, obs: Observation) -> torch.Tensor:
        m, vm = self.mission, self.vm
        pos, vel = obs.ego[..., :3], obs.ego[..., 3:]
        count = obs.sense[..., 0]
        offset = obs.sense[..., 1:3] * m.radii.sensing_m
        v_seek = torch.clamp(SEEK_GAIN * offset, -vm.max_speed_mps, vm.max_speed_mps)
        # Neighbour geometry from held states, dead-reckoned at constant velocity over
        # their P-AoI (capped: old velocities are not worth extrapolating far).
        mask = obs.nbr_mask.to(pos.dtype)
        age = torch.clamp(obs.nbr_aoi, max=DR_HORIZON_S).unsqueeze(-1)
        nbr_xy = obs.nbr_state[..., :2] + obs.nbr_state[..., 3:5] * age
        rel = nbr_xy - pos[..., :2].unsqueeze(-2)  # (B, N, N, 2) i -> j
        dist = torch.linalg.vector_norm(rel, dim=-1)
        n_nbr = mask.sum(-1, keepdim=True)
        centroid_dir = (rel * mask.unsqueeze(-1)).sum(-2) / torch.clamp(n_nbr, min=1.0)
        away = -centroid_dir / torch.clamp(torch.linalg.vector_norm(centroid_dir, dim=-1, keepdim=True), min=1e-6)
        v_explore = torch.where(n_nbr > 0, away * EXPLORE_SPEED, torch.zeros_like(away))
        n = mask.shape[-1]
        lower = torch.ones(n, n, dtype=torch.bool, device=pos.device).tril(-1)  # [i, j]: j < i
        crowded = ((dist < m.radii.sensing_m) & (mask > 0) & lower).any(-1, keepdim=True)
        away_crowd = -(rel * ((dist < m.radii.sensing_m) & (mask > 0) & lower).unsqueeze(-1)).sum(-2)
        away_crowd = away_crowd / torch.clamp(torch.linalg.vector_norm(away_crowd, dim=-1, keepdim=True), min=1e-6)
        v_explore = torch.where(crowded, away_crowd * EXPLORE_SPEED, v_explore)
        seek = (count > 0).unsqueeze(-1) & ~crowded
        v_xy = torch.where(seek, v_seek, v_explore)
        # Separation.
        close = (dist < 3 * m.radii.safe_m) & (mask > 0)
        push = -(rel / torch.clamp(dist, min=1e-6).unsqueeze(-1) * close.unsqueeze(-1)).sum(-2)
        v_xy = v_xy + 5.0 * push
        # Connectivity: pull toward the nearest known neighbour when drifting out of range.
        far_dist = torch.where(mask > 0, dist, torch.full_like(dist, float("inf")))
        nearest = far_dist.argmin(-1, keepdim=True)
        nd = far_dist.gather(-1, nearest).squeeze(-1)
        to_nearest = rel.gather(-2, nearest.unsqueeze(-1).expand(*nearest.shape, 2)).squeeze(-2)
        pull = torch.isfinite(nd) & (nd > 0.8 * m.radii.comm_m)
        v_xy = torch.where(pull.unsqueeze(-1), v_xy + 0.1 * to_nearest, v_xy)
        v_up = torch.clamp(self.alt - (-pos[..., 2]), -vm.max_climb_mps, vm.max_climb_mps) / 2.0
        v_des = torch.cat([v_xy, (-v_up).unsqueeze(-1)], -1)
        v_des = v_des * torch.clamp(vm.max_speed_mps / torch.clamp(torch.linalg.vector_norm(v_des, dim=-1, keepdim=True), min=1e-9), max=1.0)
        tau = float(m.timing.decision_every_s)
        return velocity_tracking_accel(vel, v_des, vm.max_accel_mps2, time_const=tau)
