"""Neighbour-state predictors with one interface: `forward(buf, aoi) -> next state`.

* buf (..., L, 6): the last L reconstructed states of each neighbour, oldest first,
  physical units in the mission frame (NED metres, m/s); buf[..., -1, :] is the belief
  at t - 1. Any leading batch shape (the twin's (B, N, N), an agent's (M,)).
* aoi (...): P-AoI of the neighbour at t, seconds (>= 1).
* returns (..., 6): the belief at t, one physics step (dt seconds) after buf[..., -1, :].

All three are rolled out autoregressively by `plmarl_sitl.learning.nn.belief.BeliefTracker`.
Inputs are made translation invariant: positions are taken relative to buf[..., -1, :].
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

POS_SCALE = 50.0  # m: relative positions in the buffer are divided by this
AOI_SCALE = 50.0  # s


def _relative_buffer(buf: torch.Tensor, v_max: float, pos_scale: float) -> torch.Tensor:
    """(R, L, 6) -> (R, L, 6): positions relative to the newest entry / pos_scale, velocities / v_max."""
    last = buf[:, -1:, 0:3]
    rel = (buf[..., 0:3] - last) / pos_scale
    return torch.cat([rel, buf[..., 3:6] / v_max], -1)


class ConstantVelocity(nn.Module):
    """Dead reckoning: p <- p + v dt, v <- v. No parameters, no learning."""

    def __init__(self, dt: float = 1.0, buffer_len: int = 10) -> None:
        super().__init__()
        self.dt = dt
        self.buffer_len = buffer_len

    def forward(self, buf: torch.Tensor, aoi: torch.Tensor) -> torch.Tensor:
        last = buf[..., -1, :]
        return torch.cat([last[..., 0:3] + last[..., 3:6] * self.dt, last[..., 3:6]], -1)


class StaleHold(nn.Module):
    """TAG-MAPPO's "engine": no inference, the belief stays the last received state."""

    def __init__(self, dt: float = 1.0, buffer_len: int = 10) -> None:
        super().__init__()
        self.dt = dt
        self.buffer_len = buffer_len

    def forward(self, buf: torch.Tensor, aoi: torch.Tensor) -> torch.Tensor:
        return buf[..., -1, :]


def input_transform(buffer_len: int, v_max: float, pos_scale: float, aoi_scale: float) -> torch.Tensor:
    """(L*6 + 1, L*6 + 1) fixed matrix T: [flat buffer, aoi] @ T = the normalised input.

    Positions become relative to the newest entry and are divided by pos_scale (this is
    linear in the flat buffer, so translation invariance costs no extra op at run time),
    velocities are divided by v_max and the P-AoI by aoi_scale.
    """
    d = buffer_len * 6 + 1
    t = torch.zeros(d, d)
    newest = (buffer_len - 1) * 6
    for k in range(buffer_len):
        for a in range(3):
            col = k * 6 + a
            t[col, col] += 1.0 / pos_scale
            t[newest + a, col] -= 1.0 / pos_scale
        for a in range(3, 6):
            t[k * 6 + a, k * 6 + a] = 1.0 / v_max
    t[d - 1, d - 1] = 1.0 / aoi_scale
    return t


class KinematicPredictor(nn.Module):
    """phi: MLP (64, 32) on the flattened buffer + P-AoI, with a kinematic prior.

    The network predicts the neighbour's acceleration a_hat, bounded by A_max (tanh), and
    the state is advanced with the point-mass model: p + v dt + a dt^2 / 2, v + a dt.
    With a_hat = 0 this is exactly constant-velocity dead reckoning, which is where the
    zero-initialised output layer starts. The input normalisation (relative positions,
    scales) is a fixed linear map folded into the first layer's input (`input_transform`).
    """

    def __init__(
        self, buffer_len: int = 10, hidden: tuple[int, int] = (64, 32), dt: float = 1.0, v_max: float = 20.0, a_max: float = 5.0
    ) -> None:
        super().__init__()
        self.buffer_len = buffer_len
        self.dt, self.v_max, self.a_max = dt, v_max, a_max
        self.pos_scale, self.aoi_scale = POS_SCALE, AOI_SCALE
        self.register_buffer("T", input_transform(buffer_len, v_max, POS_SCALE, AOI_SCALE), persistent=False)
        self.l1 = nn.Linear(buffer_len * 6 + 1, hidden[0])
        self.l2 = nn.Linear(hidden[0], hidden[1])
        self.l3 = nn.Linear(hidden[1], 3)
        nn.init.zeros_(self.l3.weight)
        nn.init.zeros_(self.l3.bias)
        eye, zero = torch.eye(3), torch.zeros(3, 3)
        # [p, v, u] -> [p + v dt + a dt^2 / 2, v + a dt] with a = a_max * u, u = tanh(.).
        k = torch.cat([torch.cat([eye, zero], 1), torch.cat([eye * dt, eye], 1)], 0)
        g = torch.cat([eye * (0.5 * dt * dt * a_max), eye * (dt * a_max)], 1)
        self.register_buffer("KG", torch.cat([k, g], 0), persistent=False)  # (9, 6)

    def forward(self, buf: torch.Tensor, aoi: torch.Tensor) -> torch.Tensor:
        x = torch.cat([buf.flatten(-2), aoi.unsqueeze(-1)], -1)
        # The MLP is tanh(l3(tanh(l2(tanh(l1(x @ T)))))), evaluated in its sigmoid form:
        # tanh(a) = 2 sigmoid(2a) - 1, with the factors folded into the weights,
        #   s1 = sigmoid(2 a1),  a2 = l2(2 s1 - 1) = (2 W2) s1 + (b2 - W2 1),
        #   s2 = sigmoid(2 a2),  a3 = (2 W3) s2 + (b3 - W3 1),  u = tanh(a3).
        # Same function and parameters; ATen's float tanh is scalar code (~10x slower than
        # sigmoid), and the weight expressions are constants once the file is frozen.
        w2, w3 = self.l2.weight, self.l3.weight
        s1 = torch.sigmoid(F.linear(x, (self.l1.weight @ self.T.t()) * 2.0, self.l1.bias * 2.0))
        s2 = torch.sigmoid(F.linear(s1, w2 * 4.0, (self.l2.bias - w2.sum(1)) * 2.0))
        u = torch.tanh(F.linear(s2, w3 * 2.0, self.l3.bias - w3.sum(1)))
        return torch.cat([buf.select(-2, -1), u], -1) @ self.KG


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
        lead = buf.shape[:-2]
        flat = buf.reshape(-1, self.buffer_len, 6)
        x = _relative_buffer(flat, self.v_max, self.pos_scale)
        a = (aoi.reshape(-1) / self.aoi_scale).to(x.dtype).view(-1, 1, 1).expand(x.shape[0], x.shape[1], 1)
        _, h = self.gru(torch.cat([x, a], -1))
        o = self.head(h[-1])
        last = flat[:, -1]
        out = torch.cat([last[:, 0:3] + o[:, 0:3] * self.pos_scale, o[:, 3:6] * self.v_max], -1)
        return out.reshape(lead + (6,))


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
