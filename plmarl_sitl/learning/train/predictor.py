"""Train a neighbour-state predictor phi (or the GRU baseline) through the belief tracker.

The predictor is trained exactly as it runs: inside `BeliefTracker`, autoregressively,
on true UAV trajectories from the twin with a sparse signalling schedule per sequence
(T_up drawn from 5..50 s, plus randomly lost updates). Gradients flow through the whole
rollout (back-propagation through time), so the loss sees compounding errors.

    L_inf = mean_t [ ||norm(s_true(t)) - norm(s_hat(t))||^2
                     + lambda * ||PE(dp_true(t)) - PE(dp_hat(t))||^2 / dim(PE) ]

over the seconds where the tracker predicts (not at receptions). norm() divides
positions by 50 m and velocities by V_max. dp = p_j - p_i is the displacement from an
observer i (another UAV of the same episode). PE here is a FIXED sinusoidal encoding of
dp on wavelengths 50..800 m per axis: the fusion's PE is learnt later by MAPPO, and
using it in L_inf would chain the two trainings.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import torch

from plmarl_sitl.learning.nn.belief import NEVER, BeliefTracker
from plmarl_sitl.learning.nn.predictor import ConstantVelocity

PE_WAVELENGTHS_M = (50.0, 100.0, 200.0, 400.0, 800.0)
POS_NORM, VEL_NORM = 50.0, 20.0


def fixed_pe(dp: torch.Tensor) -> torch.Tensor:
    """(..., 3) metres -> (..., 3 * 2 * len(PE_WAVELENGTHS_M))."""
    w = torch.tensor([2 * math.pi / lam for lam in PE_WAVELENGTHS_M], dtype=dp.dtype)
    x = dp.unsqueeze(-1) * w  # (..., 3, K)
    return torch.cat([torch.sin(x), torch.cos(x)], -1).flatten(-2)


def schedule(
    t_len: int, tup: torch.Tensor, p_drop: float, gen: torch.Generator | None, phase: torch.Tensor | None = None
) -> torch.Tensor:
    """(R,) T_up per row -> held_t_rx (R, t_len): last received signalling time <= t (NEVER before).

    Updates arrive at t = phase + k T_up (phase 0 by default), each lost with p_drop
    (never the first one).
    """
    t = torch.arange(t_len).unsqueeze(0)
    ph = torch.zeros_like(tup) if phase is None else phase
    instant = ((t - ph.unsqueeze(1)) % tup.unsqueeze(1) == 0) & (t >= ph.unsqueeze(1))
    if p_drop > 0:
        drop = torch.rand(instant.shape, generator=gen) < p_drop
        first = instant & (torch.cumsum(instant.long(), 1) == 1)
        instant = instant & (~drop | first)
    rx_t = torch.where(instant, t.expand_as(instant).to(torch.float32), torch.full(instant.shape, NEVER))
    return torch.cummax(rx_t, 1).values


def rollout(tracker: BeliefTracker, traj: torch.Tensor, held_t_rx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Run the tracker over traj (R, T, 6) with the reception times (R, T) -> (beliefs (R, T, 6), aoi (R, T))."""
    r, t_len, _ = traj.shape
    idx = torch.clamp(held_t_rx, min=0).long()
    held = torch.gather(traj, 1, idx.unsqueeze(-1).expand(r, t_len, 6))
    buf, seen = tracker.init_state(traj[:, 0])
    beliefs, aois = [], []
    for t in range(t_len):
        b, a, buf, seen = tracker(float(t), held[:, t], held_t_rx[:, t], buf, seen)
        beliefs.append(b)
        aois.append(a)
    return torch.stack(beliefs, 1), torch.stack(aois, 1)


def inference_loss(
    beliefs: torch.Tensor, traj: torch.Tensor, observer: torch.Tensor, aoi_mask: torch.Tensor, lam: float
) -> torch.Tensor:
    dp_err = (beliefs[..., :3] - traj[..., :3]) / POS_NORM
    dv_err = (beliefs[..., 3:] - traj[..., 3:]) / VEL_NORM
    mse = (dp_err.pow(2).sum(-1) + dv_err.pow(2).sum(-1)) / 6.0
    pe_t = fixed_pe(traj[..., :3] - observer[..., :3])
    pe_h = fixed_pe(beliefs[..., :3] - observer[..., :3])
    pe = (pe_t - pe_h).pow(2).mean(-1)
    w = aoi_mask.to(mse.dtype)
    return ((mse + lam * pe) * w).sum() / torch.clamp(w.sum(), min=1.0)


@dataclass
class PredictorArgs:
    iters: int = 600
    rows: int = 512
    lr: float = 3e-3
    lam: float = 1.0
    p_drop: float = 0.1
    tup_choices: tuple[int, ...] = (5, 10, 15, 20, 25, 30, 35, 40, 45, 50)
    window: int = 80  # seconds per training sequence (truncated BPTT)
    seed: int = 0


def train_predictor(
    tracker: BeliefTracker, traj: torch.Tensor, observers: torch.Tensor, args: PredictorArgs, log=print,
    on_iter: Callable[[int], None] | None = None,
) -> list[dict]:
    """traj, observers: (R, T, 6). Trains tracker.predictor in place; returns the loss curve.
    `on_iter(done)` after each iteration (a progress bar)."""
    gen = torch.Generator().manual_seed(args.seed)
    opt = torch.optim.Adam(tracker.predictor.parameters(), lr=args.lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, args.iters, eta_min=args.lr * 0.05)
    choices = torch.tensor(args.tup_choices)
    curve = []
    t0 = time.time()
    for it in range(args.iters):
        rows = torch.randint(0, traj.shape[0], (args.rows,), generator=gen)
        w = min(args.window, traj.shape[1])
        t0_ = int(torch.randint(0, traj.shape[1] - w + 1, (1,), generator=gen))
        seq, obs = traj[rows, t0_ : t0_ + w], observers[rows, t0_ : t0_ + w]
        tup = choices[torch.randint(0, len(choices), (args.rows,), generator=gen)]
        rx = schedule(w, tup, args.p_drop, gen)
        beliefs, _ = rollout(tracker, seq, rx)
        t = torch.arange(w).unsqueeze(0).to(rx.dtype)
        predicting = rx < t  # seconds where the tracker predicted
        loss = inference_loss(beliefs, seq, obs, predicting, args.lam)
        opt.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(tracker.predictor.parameters(), 1.0)
        opt.step()
        sched.step()
        curve.append({"iter": it, "loss": float(loss.detach()), "wall_s": time.time() - t0})
        if it % 50 == 0 or it == args.iters - 1:
            log(f"predictor iter {it:4d} loss {float(loss.detach()):.5f} ({time.time() - t0:.0f} s)")
        if on_iter is not None:
            on_iter(it + 1)
    return curve


@torch.no_grad()
def position_errors(
    tracker: BeliefTracker, traj: torch.Tensor, ages: tuple[int, ...] = (10, 25, 50), tup: int = 60, seed: int = 0
) -> dict[int, float]:
    """Mean position error (m) at each P-AoI in `ages`, every update delivered at T_up = `tup`.

    Each row's updates start at a random phase in [0, tup), so errors are averaged over
    all flight phases (not only from the launch line); buffers hold earlier beliefs, as
    in operation. T_up = 60 s makes every age up to 59 s occur.
    """
    gen = torch.Generator().manual_seed(seed)
    phase = torch.randint(0, tup, (traj.shape[0],), generator=gen)
    rx = schedule(traj.shape[1], torch.full((traj.shape[0],), tup), 0.0, None, phase)
    beliefs, aoi = rollout(tracker, traj, rx)
    err = torch.linalg.vector_norm(beliefs[..., :3] - traj[..., :3], dim=-1)
    heard = rx > NEVER / 2
    out = {}
    for a in ages:
        sel = (aoi == a) & heard
        out[a] = float(err[sel].mean()) if bool(sel.any()) else float("nan")
    return out


def dead_reckoning_tracker(buffer_len: int = 10, dt: float = 1.0) -> BeliefTracker:
    return BeliefTracker(ConstantVelocity(dt, buffer_len), buffer_len, dt)


def pair_rows(traj: torch.Tensor, gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """(E, N, T, 6) episodes -> (targets (E*N, T, 6), observers (E*N, T, 6)): each UAV with another of its episode."""
    e, n, t_len, _ = traj.shape
    shift = torch.randint(1, max(n, 2), (e, n), generator=gen) if n > 1 else torch.zeros(e, n, dtype=torch.long)
    obs_idx = (torch.arange(n).unsqueeze(0) + shift) % n
    observers = torch.gather(traj, 1, obs_idx[..., None, None].expand(e, n, t_len, 6))
    return traj.reshape(e * n, t_len, 6), observers.reshape(e * n, t_len, 6)
