"""Algorithm 1's belief tracker: ONE implementation for the twin and the deployed agent.

Per neighbour j, receiver i keeps a buffer H_ij of the last L reconstructed states. Once
per physics second t:

* if a signalling update from j arrived at t (its held state is newer than the one the
  tracker last took): s_hat_ij(t) = s_j(t), the received true state, and the P-AoI resets;
* otherwise the P-AoI grows and s_hat_ij(t) = phi(H_ij(t-1), Delta_ij(t));
* s_hat_ij(t) is appended to H_ij (the oldest entry drops out).

P-AoI follows Eq. (1) as the twin computes it: Delta_ij(t) = max(1, t - t_rx).

The state is explicit tensors, so the same `BeliefTracker.forward` serves any leading
batch shape: the twin's (B, N) receivers x N senders, or one deployed agent's M
neighbours (batch shape ()). It is TorchScript-compatible; `predictor.pt` is this
module, scripted, with the predictor inside.

A neighbour heard for the first time has no history: its buffer is back-filled with the
constant-velocity past of the received state (p - k v dt, v), the only physically
consistent guess.
"""

from __future__ import annotations

import torch
from torch import nn

from plmarl_sitl.model.signalling import silent_in_range

NEVER = -1.0e9  # t_rx of a neighbour never heard (same sentinel as plmarl_sitl.model.signalling)
MAX_AOI = 1000.0  # s: P-AoI fed to the predictor is capped (never-heard slots are masked anyway)


def backfill(new_buf: torch.Tensor, held_state: torch.Tensor, fresh: torch.Tensor, unseen: torch.Tensor, dt: float) -> torch.Tensor:
    """Back-fill the buffer of a neighbour heard for the first time (fresh and never taken
    before) with the constant-velocity past of its received state: (p - k v dt, v)."""
    first = fresh & unseen
    buffer_len = new_buf.size(-2)
    k = torch.arange(buffer_len - 1, -1, -1, dtype=new_buf.dtype, device=new_buf.device) * dt
    past_p = held_state[..., None, 0:3] - held_state[..., None, 3:6] * k.unsqueeze(-1)
    past = torch.cat([past_p, held_state[..., None, 3:6].expand(past_p.shape)], -1)
    return torch.where(first[..., None, None], past, new_buf)


class BeliefTracker(nn.Module):
    def __init__(self, predictor: nn.Module, buffer_len: int = 10, dt: float = 1.0) -> None:
        super().__init__()
        self.predictor = predictor
        self.buffer_len = buffer_len
        self.dt = dt
        self.never = NEVER
        self.max_aoi = MAX_AOI

    @torch.jit.export
    def init_state(self, held_state: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Empty (buf, seen_t_rx) for held_state's shape (..., M, 6)."""
        shape = held_state.shape[:-1]
        buf = torch.zeros(shape + (self.buffer_len, 6), dtype=held_state.dtype, device=held_state.device)
        seen = torch.full(shape, self.never, dtype=held_state.dtype, device=held_state.device)
        return buf, seen

    def forward(
        self, t: float, held_state: torch.Tensor, held_t_rx: torch.Tensor, buf: torch.Tensor, seen_t_rx: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Advance every neighbour to second t.

        held_state (..., M, 6): last state received from each neighbour (any value if never);
        held_t_rx (..., M): when it was received (NEVER if never); buf (..., M, L, 6) and
        seen_t_rx (..., M): the tracker's state from the previous call (or `init_state`).
        Returns (belief (..., M, 6), aoi (..., M) (capped at MAX_AOI), buf, seen_t_rx).
        """
        fresh = (held_t_rx > seen_t_rx) & (held_t_rx <= t)
        aoi = torch.clamp(torch.rsub(held_t_rx, t), 1.0, self.max_aoi)  # Eq. (1); capped for never-heard slots
        pred = self.predictor(buf, aoi)
        belief = torch.where(fresh.unsqueeze(-1), held_state, pred)
        new_buf = torch.cat([buf.narrow(-2, 1, self.buffer_len - 1), belief.unsqueeze(-2)], -2)
        # Back-fill only matters while some slot has never been taken: one cheap check first.
        unseen = seen_t_rx <= self.never * 0.5
        if bool(unseen.any()):
            new_buf = backfill(new_buf, held_state, fresh, unseen, self.dt)
        seen = torch.where(fresh, held_t_rx, seen_t_rx)
        return belief, aoi, new_buf, seen


class Beliefs:
    """Stateful convenience wrapper around a (scripted or eager) BeliefTracker.

    `advance(t, held_state, held_t_rx)` once per physics second. The twin only shows the
    observation at decision instants, so `catch_up(t_now, ...)` replays the seconds since
    the last call with the held states of `t_now` (a held state received at second s is
    taken at s; earlier seconds predict), which is what a tracker running every second
    would have done when at most one update arrives per decision interval.
    """

    def __init__(self, tracker: nn.Module) -> None:
        self.tracker = tracker
        self.buf: torch.Tensor | None = None
        self.seen: torch.Tensor | None = None
        self.t: int | None = None
        self.belief: torch.Tensor | None = None
        self.aoi: torch.Tensor | None = None

    def reset(self) -> None:
        self.buf = self.seen = self.belief = self.aoi = None
        self.t = None

    @torch.no_grad()
    def advance(self, t: int, held_state: torch.Tensor, held_t_rx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        if self.buf is None or self.seen is None:
            self.buf, self.seen = self.tracker.init_state(held_state)
        self.belief, self.aoi, self.buf, self.seen = self.tracker(float(t), held_state, held_t_rx, self.buf, self.seen)
        self.t = t
        return self.belief, self.aoi

    def catch_up(self, t_now: int, held_state: torch.Tensor, held_t_rx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        start = 0 if self.t is None else self.t + 1
        for s in range(start, t_now + 1):
            self.advance(s, held_state, held_t_rx)
        assert self.belief is not None and self.aoi is not None
        return self.belief, self.aoi


class FailureFlags:
    """The agents' failure flags f in the twin, latched per episode: f_i is set when a
    neighbour leaves N_i while its belief is still within R_comm of agent i
    (`plmarl_sitl.model.signalling.silent_in_range`, the rule the deployed agent's
    neighbour table applies at the instant it drops a neighbour). Call `update` at every
    observation, with the beliefs of that instant."""

    def __init__(self, comm_m: float) -> None:
        self.comm_m = comm_m
        self.was: torch.Tensor | None = None
        self.flag: torch.Tensor | None = None

    def reset(self) -> None:
        self.was = self.flag = None

    def update(self, mask: torch.Tensor, belief: torch.Tensor, ego: torch.Tensor, alive: torch.Tensor) -> torch.Tensor:
        """mask (..., M) bool N_i, belief (..., M, 6), ego (..., 6), alive (...) -> f (...) bool."""
        if self.was is None or self.flag is None:
            self.was, self.flag = torch.zeros_like(mask), torch.zeros_like(alive)
        dropped = self.was & ~mask
        self.flag = self.flag | silent_in_range(dropped, belief[..., 0:3], ego[..., 0:3], self.comm_m)
        self.was = mask
        return self.flag & alive
