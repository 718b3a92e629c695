"""Radio channel: Al-Hourani air-to-ground model and UAV-to-UAV SINR.

A2G mean path loss (Al-Hourani et al., 2014), elevation angle theta in degrees:

    P_LoS(theta) = 1 / (1 + a exp(-b (theta - a)))
    PL = FSPL(d_3d, f) + P_LoS * eta_LoS + (1 - P_LoS) * eta_NLoS        [dB]

At a fixed altitude PL grows monotonically with ground distance (FSPL grows, elevation
falls so P_LoS falls), so "PL <= threshold" is the same as "ground distance <= r_PL(h)".
`CoverageRadius` solves r_PL once on an altitude grid, which keeps every transcendental
function off the user x UAV hot path.
"""

from __future__ import annotations

import functools
import math

import torch

from plmarl_sitl.mission import Channel

_C = 299_792_458.0


def fspl_db(dist_m: torch.Tensor, freq_hz: float) -> torch.Tensor:
    """Free-space path loss in dB (distance clamped to 1 m)."""
    d = torch.clamp(dist_m, min=1.0)
    return 20.0 * torch.log10(d) + 20.0 * math.log10(4.0 * math.pi * freq_hz / _C)


def los_probability(elevation_deg: torch.Tensor, a: float, b: float) -> torch.Tensor:
    return 1.0 / (1.0 + a * torch.exp(-b * (elevation_deg - a)))


def a2g_path_loss_db(ground_dist_m: torch.Tensor, alt_m: torch.Tensor, ch: Channel) -> torch.Tensor:
    """Mean A2G path loss between a UAV at `alt_m` and a user `ground_dist_m` away."""
    d3 = torch.sqrt(ground_dist_m**2 + alt_m**2)
    elev = torch.rad2deg(torch.atan2(alt_m, ground_dist_m))
    p = los_probability(elev, ch.los_a, ch.los_b)
    return fspl_db(d3, ch.carrier_ghz * 1e9) + p * ch.eta_los_db + (1.0 - p) * ch.eta_nlos_db


class CoverageRadius:
    """r_max(h) = min(R_s, r_PL(h)): the ground radius a UAV at altitude h covers.

    Tabulated every `step_m` of altitude in float64 by bisection, looked up by linear
    interpolation (r_PL is smooth in h, so the table error is far below a metre).
    """

    def __init__(self, ch: Channel, sensing_m: float, alt_min: float, alt_max: float, step_m: float = 0.5):
        self.alt_min, self.step = float(alt_min), float(step_m)
        n = int(math.ceil((alt_max - alt_min) / step_m)) + 1
        alts = torch.linspace(alt_min, alt_min + (n - 1) * step_m, n, dtype=torch.float64)
        lo = torch.zeros_like(alts)
        hi = torch.full_like(alts, float(sensing_m))
        # Bisection on the monotone function PL(r) - threshold.
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            inside = a2g_path_loss_db(mid, alts, ch) <= ch.max_path_loss_db
            lo = torch.where(inside, mid, lo)
            hi = torch.where(inside, hi, mid)
        full = a2g_path_loss_db(torch.full_like(alts, float(sensing_m)), alts, ch) <= ch.max_path_loss_db
        none = a2g_path_loss_db(torch.zeros_like(alts), alts, ch) > ch.max_path_loss_db
        radius = torch.where(full, torch.full_like(alts, float(sensing_m)), lo)
        self.alts = alts
        self.table = torch.where(none, torch.zeros_like(radius), radius)

    def __call__(self, alt_m: torch.Tensor) -> torch.Tensor:
        table = self.table.to(alt_m.dtype)
        x = torch.clamp((alt_m - self.alt_min) / self.step, 0.0, len(table) - 1.0)
        i0 = torch.clamp(x.floor().long(), max=len(table) - 2) if len(table) > 1 else x.long()
        if len(table) == 1:
            return table[i0]
        w = x - i0.to(x.dtype)
        return table[i0] * (1.0 - w) + table[i0 + 1] * w

    def best_altitude(self) -> tuple[float, float]:
        """(altitude, radius): the middle of the altitude plateau with the largest radius,
        so a small altitude error costs no coverage."""
        best = float(self.table.max())
        idx = torch.nonzero(self.table >= best - 1e-6).flatten()
        mid = int(idx[len(idx) // 2])
        return float(self.alts[mid]), best


@functools.lru_cache(maxsize=16)
def coverage_radius(ch: Channel, sensing_m: float, alt_min: float, alt_max: float) -> CoverageRadius:
    """The CoverageRadius of these constants, tabulated once per process and shared (read
    only): an agent asked for it twice while it starts, and a SITL swarm's forkserver builds
    it once for every agent it forks (issue 25: start-up at N = 100)."""
    return CoverageRadius(ch, sensing_m, alt_min, alt_max)


def mission_coverage(mission) -> tuple[float, float]:  # noqa: ANN001 - Mission
    """(altitude, radius) of the largest coverage radius in the mission vehicle's altitude band:
    where the plan and the plan followers fly, and how far a plan point serves."""
    vm = mission.vehicle_model()
    return coverage_radius(mission.channel, mission.radii.sensing_m, vm.min_alt_m, vm.max_alt_m).best_altitude()


def db_to_lin(db: torch.Tensor | float) -> torch.Tensor | float:
    return 10.0 ** (db / 10.0)


def u2u_sinr(pos: torch.Tensor, alive: torch.Tensor, ch: Channel) -> torch.Tensor:
    """Linear SINR of the link j -> i, shape (..., N, N) indexed [i, j] (receiver i).

    Air-to-air links are line of sight (free space). Every other live UAV k interferes
    at receiver i with its received power times `interference_activity`, the chance that
    it transmits in the same slot. Entries with i == j or a dead end are 0.
    """
    diff = pos.unsqueeze(-2) - pos.unsqueeze(-3)  # [..., i, j, :] = p_i - p_j
    dist = torch.linalg.vector_norm(diff, dim=-1)
    rx_dbm = ch.tx_power_dbm - fspl_db(dist, ch.u2u_carrier_ghz * 1e9)
    n = pos.shape[-2]
    eye = torch.eye(n, dtype=torch.bool, device=pos.device)
    live_pair = alive.unsqueeze(-1) & alive.unsqueeze(-2) & ~eye
    rx_mw = torch.where(live_pair, db_to_lin(rx_dbm), torch.zeros_like(rx_dbm))
    total_at_i = rx_mw.sum(-1, keepdim=True)  # all live transmitters heard at i
    interference = ch.interference_activity * (total_at_i - rx_mw)
    noise = db_to_lin(ch.noise_dbm)
    return torch.where(live_pair, rx_mw / (interference + noise), torch.zeros_like(rx_mw))
