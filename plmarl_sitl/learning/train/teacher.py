"""The CTDE imitation teachers (training only; the student sees only its own beliefs and sensing):
`ReactTargets` reacts at once to a failure, `joint_track` follows moving crowds (below).

The react teacher: the team plan re-solved the second a UAV fails, from the true positions of
the survivors.

Why: the plan follower `service` (and a student imitating it) learns of a failure only from
missed signalling instants (`drop_after_missed` of them, then gossip hops): 30-100 s at
T_up 15-50. In the twin a teacher may know the failure and every teammate's state (the
letter's centralised training). Its action is "fly to your point of the plan re-solved for the
true failed set at the failure, assigned by least travel from where the survivors really
are". A student that imitates it sees only what it would see deployed (its beliefs with their
ages, the failure flag f "predicted in range, yet silent", its own plan point), so whatever it
learns of reacting before the declaration it must infer from those.
"""

from __future__ import annotations

import numpy as np
import torch

from plmarl_sitl.learning.nn.plan import ServiceTargets
from plmarl_sitl.model.gossip import Gossip
from plmarl_sitl.model.placement import components


class ReactTargets(ServiceTargets):
    """`ServiceTargets` whose failure knowledge is the twin's truth: every copy re-plans at the
    first decision a UAV is dead, for epoch = that second, from the true positions."""

    def update_true(self, obs) -> torch.Tensor:  # noqa: ANN001 - twin.env.Observation
        """The teacher's targets (B, N, 2) at this decision."""
        if self.plans is None:  # the plan-aware motion (which a re-plan replays) needs a gossip at the first call
            gossip = Gossip(obs.ego.shape[0], obs.ego.shape[1])
        else:
            gossip = obs.gossip
        return self.update(obs.t, obs.ego, obs.nbr_state, obs.nbr_t_rx, obs.demand, mask=obs.nbr_mask,
                           alive=obs.alive, gossip=gossip)

    def on_failures(self, t: int, mask: torch.Tensor, alive: torch.Tensor, gossip: Gossip, t_rx: torch.Tensor,
                    ego: torch.Tensor, held: torch.Tensor) -> None:
        plans = self.plans
        assert plans is not None and plans.motion is not None
        dead = ~alive.numpy()  # (B, N)
        live = alive.numpy()
        stale = live & (plans.failed != dead[:, None, :]).any(-1)
        true_xy = ego[..., :2].double().numpy()  # (B, N, 2): every identity's true position
        for e, a in zip(*np.nonzero(stale), strict=True):
            plans.replan(int(e), int(a), dead[e].copy(), int(t), true_xy[e])
            self.replans_done += 1


def _count_components(xy: np.ndarray, link_m: float | np.ndarray) -> int:
    """Connected components of the points (n, 2), an edge where two are within link_m (a number,
    or (n, n) per pair)."""
    return len(np.unique(components(xy, link_m, skip=-1))) if len(xy) else 0


def joint_track(target: torch.Tensor, ego: torch.Tensor, sense: torch.Tensor, alive: torch.Tensor, *, radius_m: float,
                leash_m: float, link_m: float, apart_m: float, margin_m: float | None = None,
                fracs: tuple[float, ...] = (1.0, 0.5, 0.25)) -> torch.Tensor:
    """A centralised tracking teacher (CTDE, issue 24.3; training only): every live UAV's plan point
    `target` (B, N, 2) moved toward the centroid in `sense` (over `radius_m`) by at most `leash_m`,
    agents taken by the length of their step (longest first), each with the largest fraction in
    `fracs` that keeps, over the team's current points (its teammates' true chosen points,
    knowledge no agent has deployed): no more link components (edges <= link_m) than the plan's own
    points, and no pair closer than min(apart_m, its distance in the plan). A fraction that breaks
    either is not taken (the point stays where the smaller fractions put it, or on the plan).
    `margin_m` (<= link_m; default link_m): a pair linked in the plan stays linked while its distance is
    at most max(margin_m, its plan distance), a pair not linked in the plan links within margin_m:
    below link_m it keeps a margin for a student's error, and link_m itself is the plain check."""
    margin = link_m if margin_m is None else min(margin_m, link_m)
    plan = target.double().numpy()
    centroid = (ego[..., :2] + sense[..., 1:3] * radius_m).double().numpy()
    has = (sense[..., 0] > 0).numpy() & alive.numpy()
    step = centroid - plan
    norm = np.sqrt((step**2).sum(-1, keepdims=True))
    step = step * np.minimum(1.0, leash_m / np.maximum(norm, 1e-9))
    step[~has] = 0.0
    out = plan.copy()
    live = alive.numpy()
    for e in range(plan.shape[0]):
        idx = np.nonzero(live[e])[0]
        if len(idx) < 2:
            out[e, idx] = plan[e, idx] + step[e, idx]
            continue
        p0 = plan[e, idx]
        base_comps = _count_components(p0, link_m)
        d0 = np.sqrt(((p0[:, None] - p0[None]) ** 2).sum(-1))
        reach = np.where(d0 <= link_m, np.maximum(margin, d0), margin)  # a moved pair is linked within this
        floor = np.minimum(apart_m, d0) - 1e-6
        np.fill_diagonal(floor, -np.inf)
        cur = p0.copy()
        order = np.argsort(-np.sqrt((step[e, idx] ** 2).sum(-1)), kind="stable")
        for j in order:
            if not np.any(step[e, idx[j]]):
                continue
            for f in fracs:
                cand = cur.copy()
                cand[j] = p0[j] + f * step[e, idx[j]]
                dj = np.sqrt(((cand - cand[j]) ** 2).sum(-1))
                if np.any(dj < floor[j]) or _count_components(cand, reach) > base_comps:
                    continue
                cur = cand
                break
        out[e, idx] = cur
    return torch.from_numpy(out).to(target.dtype)


__all__ = ["ReactTargets", "joint_track"]
