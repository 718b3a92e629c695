"""Sparse signalling: P-AoI (Eq. 1) and what each agent holds of its neighbours.

Node j broadcasts its true state only at t = k T_up. Receiver i keeps the last state it
received from j, when it was received, and how many signalling instants in a row it has
missed. j is in i's neighbour set N_i while fewer than `drop_after_missed` consecutive
instants were missed. The P-AoI is max(1, t - t_rx): Eq. (1) exactly when every update
arrives (1 at the instant, t - k T_up between), and still growing when updates are lost.
(Algorithm 1's "reset to 1, then +1 per step" is one larger than Eq. (1) between
instants; we follow the equation.)
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch

NEVER = -1.0e9  # t_rx of a neighbour never heard


def paoi(t: torch.Tensor | float, tup: int) -> torch.Tensor:
    """Eq. (1): P-AoI at integer time t with every update delivered."""
    t = torch.as_tensor(t)
    since = torch.remainder(t, tup)
    return torch.where(since == 0, torch.ones_like(since), since)


def is_signalling_instant(t: int, tup: int) -> bool:
    return t % tup == 0


@dataclass(frozen=True)
class Holdings:
    """What each receiver i holds of each sender j; tensors are (..., N, N) [i, j]."""

    state: torch.Tensor  # (..., N, N, 6) last received [pos, vel] of j
    t_rx: torch.Tensor  # time it was received (NEVER if never)
    missed: torch.Tensor  # consecutive signalling instants missed since
    ever: torch.Tensor  # bool: j has ever been heard
    lost: torch.Tensor  # bool (..., N): i dropped a neighbour it had (failure state f_i)

    @classmethod
    def empty(cls, batch_shape: tuple[int, ...], n: int, dtype: torch.dtype, device: str = "cpu") -> Holdings:
        z = torch.zeros(*batch_shape, n, n, dtype=dtype, device=device)
        return cls(
            state=torch.zeros(*batch_shape, n, n, 6, dtype=dtype, device=device),
            t_rx=torch.full_like(z, NEVER),
            missed=torch.zeros_like(z),
            ever=torch.zeros_like(z, dtype=torch.bool),
            lost=torch.zeros(*batch_shape, n, dtype=torch.bool, device=device),
        )

    def neighbour_mask(self, drop_after_missed: int) -> torch.Tensor:
        return self.ever & (self.missed < drop_after_missed)

    def aoi(self, t: torch.Tensor | float) -> torch.Tensor:
        t = torch.as_tensor(t, dtype=self.t_rx.dtype, device=self.t_rx.device)
        if t.dim() > 0:
            t = t.view(*t.shape, *([1] * (self.t_rx.dim() - t.dim())))
        return torch.clamp(t - self.t_rx, min=1.0)


def signalling_update(
    h: Holdings, t: torch.Tensor | float, received: torch.Tensor, true_state: torch.Tensor, drop_after_missed: int
) -> Holdings:
    """Apply one signalling instant. `received[..., i, j]`: i got j's broadcast now.

    true_state (..., N, 6) is every sender's state at the instant.
    """
    n = received.shape[-1]
    eye = torch.eye(n, dtype=torch.bool, device=received.device)
    got = received & ~eye
    t = torch.as_tensor(t, dtype=h.t_rx.dtype, device=h.t_rx.device)
    if t.dim() > 0:
        t = t.view(*t.shape, 1, 1)
    sent = true_state.unsqueeze(-3).expand_as(h.state)  # [.., i, j] = state of j
    was = h.neighbour_mask(drop_after_missed)
    missed = torch.where(got, torch.zeros_like(h.missed), torch.where(eye, h.missed, h.missed + 1))
    new = replace(
        h,
        state=torch.where(got.unsqueeze(-1), sent, h.state),
        t_rx=torch.where(got, t.expand_as(h.t_rx), h.t_rx),
        missed=missed,
        ever=h.ever | got,
    )
    dropped = (was & ~new.neighbour_mask(drop_after_missed)).any(-1)
    return replace(new, lost=h.lost | dropped)


def silent_in_range(dropped: torch.Tensor, belief_pos: torch.Tensor, own_pos: torch.Tensor, comm_m: float) -> torch.Tensor:
    """The failure evidence of one receiver: "predicted in range, yet silent".

    dropped (..., M) bool: neighbours that just left N_i (missed `drop_after_missed`
    signalling instants in a row); belief_pos (..., M, 3): where the receiver's predictor
    believes they are now; own_pos (..., 3): the receiver's position. Returns (...) bool:
    some dropped neighbour is still believed within R_comm. A neighbour that flew out of
    range is believed out of range and is not evidence of a failure.

    The failure flag f_i latches it: `f_i = f_i | silent_in_range(...)`, at the instant
    the drop is noticed. The twin's learners (plmarl_sitl.learning.nn.belief.FailureFlags)
    and the deployed agent's neighbour table apply this same rule.
    """
    d = belief_pos - own_pos.unsqueeze(-2)
    near = (d * d).sum(-1) <= comm_m * comm_m
    return (dropped & near).any(-1)
