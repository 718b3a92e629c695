"""Neighbour-state predictors with one interface: `forward(buf, aoi) -> next state`.

* buf (R, L, 6): the last L reconstructed states of R neighbours, oldest first, physical
  units in the mission frame (NED metres, m/s); buf[:, -1] is the belief at t - 1.
* aoi (R,): P-AoI of the neighbour at t, seconds (>= 1).
* returns (R, 6): the belief at t, one physics step (dt seconds) after buf[:, -1].

All three are rolled out autoregressively by `plmarl_sitl.nn.belief.BeliefTracker`.
Inputs are made translation invariant: positions are taken relative to buf[:, -1].
"""

from __future__ import annotations

import torch
from torch import nn

POS_SCALE = 50.0  # m: relative positions in the buffer are divided by this
AOI_SCALE = 50.0  # s


def _relative_buffer(buf: torch.Tensor, v_max: float, pos_scale: float) -> torch.Tensor:
    """(R, L, 6) -> (R, L, 6): positions relative to the newest entry / pos_scale, velocities / v_max."""
    last = buf[:, -1:, 0:3]
    rel = (buf[..., 0:3] - last) / pos_scale
    return torch.cat([rel, buf[..., 3:6] / v_max], -1)


def _clip_speed(v: torch.Tensor, v_max: float) -> torch.Tensor:
    n = torch.linalg.vector_norm(v, dim=-1, keepdim=True)
    return v * torch.clamp(v_max / torch.clamp(n, min=1e-9), max=1.0)


class ConstantVelocity(nn.Module):
    """Dead reckoning: p <- p + v dt, v <- v. No parameters, no learning."""

    def __init__(self, dt: float = 1.0, buffer_len: int = 10) -> None:
        super().__init__()
        self.dt = dt
        self.buffer_len = buffer_len

    def forward(self, buf: torch.Tensor, aoi: torch.Tensor) -> torch.Tensor:
        last = buf[:, -1]
        return torch.cat([last[:, 0:3] + last[:, 3:6] * self.dt, last[:, 3:6]], -1)


class StaleHold(nn.Module):
    """TAG-MAPPO's "engine": no inference, the belief stays the last received state."""

    def __init__(self, dt: float = 1.0, buffer_len: int = 10) -> None:
        super().__init__()
        self.dt = dt
        self.buffer_len = buffer_len

    def forward(self, buf: torch.Tensor, aoi: torch.Tensor) -> torch.Tensor:
        return buf[:, -1]


class KinematicPredictor(nn.Module):
    """phi: MLP (64, 32) on the flattened buffer + P-AoI, with a kinematic prior.

    The network predicts the neighbour's acceleration a_hat, bounded by A_max (tanh), and
    the state is advanced with the point-mass model: p + v dt + a dt^2 / 2, v + a dt
    (speed clipped to V_max). With a_hat = 0 this is exactly constant-velocity dead
    reckoning, which is where the zero-initialised output layer starts.
    """

    def __init__(
        self, buffer_len: int = 10, hidden: tuple[int, int] = (64, 32), dt: float = 1.0, v_max: float = 20.0, a_max: float = 5.0
    ) -> None:
        super().__init__()
        self.buffer_len = buffer_len
        self.dt, self.v_max, self.a_max = dt, v_max, a_max
        self.pos_scale, self.aoi_scale = POS_SCALE, AOI_SCALE
        self.net = nn.Sequential(
            nn.Linear(buffer_len * 6 + 1, hidden[0]),
            nn.Tanh(),
            nn.Linear(hidden[0], hidden[1]),
            nn.Tanh(),
            nn.Linear(hidden[1], 3),
        )
        last = self.net[-1]
        assert isinstance(last, nn.Linear)
        nn.init.zeros_(last.weight)
        nn.init.zeros_(last.bias)

    def forward(self, buf: torch.Tensor, aoi: torch.Tensor) -> torch.Tensor:
        x = _relative_buffer(buf, self.v_max, self.pos_scale).flatten(1)
        x = torch.cat([x, (aoi / self.aoi_scale).unsqueeze(-1).to(x.dtype)], -1)
        acc = self.a_max * torch.tanh(self.net(x))
        last = buf[:, -1]
        p, v = last[:, 0:3], last[:, 3:6]
        v_new = _clip_speed(v + acc * self.dt, self.v_max)
        p_new = p + 0.5 * (v + v_new) * self.dt
        return torch.cat([p_new, v_new], -1)


class GRUPredictor(nn.Module):
    """GRU-MARL's engine: a GRU over the buffer (sequential unrolling), no physics prior.

    It sees the same translation-invariant buffer and the P-AoI at every step, and
    outputs the next state directly (displacement from the newest entry / POS_SCALE and
    velocity / V_max), so any kinematics must be learnt from data.
    """

    def __init__(self, buffer_len: int = 10, hidden: int = 64, dt: float = 1.0, v_max: float = 20.0) -> None:
        super().__init__()
        self.buffer_len = buffer_len
        self.dt, self.v_max = dt, v_max
        self.pos_scale, self.aoi_scale = POS_SCALE, AOI_SCALE
        self.gru = nn.GRU(7, hidden, batch_first=True)
        self.head = nn.Linear(hidden, 6)

    def forward(self, buf: torch.Tensor, aoi: torch.Tensor) -> torch.Tensor:
        x = _relative_buffer(buf, self.v_max, self.pos_scale)
        a = (aoi / self.aoi_scale).to(x.dtype).view(-1, 1, 1).expand(x.shape[0], x.shape[1], 1)
        _, h = self.gru(torch.cat([x, a], -1))
        o = self.head(h[-1])
        last = buf[:, -1]
        return torch.cat([last[:, 0:3] + o[:, 0:3] * self.pos_scale, o[:, 3:6] * self.v_max], -1)


def make_predictor(kind: str, buffer_len: int = 10, dt: float = 1.0, v_max: float = 20.0, a_max: float = 5.0) -> nn.Module:
    if kind == "mlp":
        return KinematicPredictor(buffer_len, dt=dt, v_max=v_max, a_max=a_max)
    if kind == "gru":
        return GRUPredictor(buffer_len, dt=dt, v_max=v_max)
    if kind == "cv":
        return ConstantVelocity(dt, buffer_len)
    if kind == "hold":
        return StaleHold(dt, buffer_len)
    raise ValueError(f"unknown predictor kind {kind!r} (mlp, gru, cv, hold)")
