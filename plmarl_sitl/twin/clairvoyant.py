"""Clairvoyant reference (method `clairvoyant`): the best of several plans, re-chosen every
decision with true states and true user positions, flown with the same dynamics.

Why: the greedy placement (`greedy.py`, "the Oracle" before issue 24) is one greedy plan,
kept until another greedy plan covers more; the plan follower `service` beats it by 1-3 %
on several families, so it is no bound. This reference is stronger by construction. At
every decision it sees every user and every UAV (no signalling, no staleness) and scores
these candidate plans, each a set of targets assigned to the live UAVs:

1. the plan it flies now (so it only switches for something better);
2. the greedy reference's own plan, run beside it on the same state (`GreedyController.
   plan_targets`): the greedy is always a candidate;
3. fresh greedy plans on the true users from FIRSTS different first points (the plain
   greedy, then the next best well-separated peaks of the coverage map), and the service
   plan (model/service.py `ServiceGrid.place`) on a demand map of the true users; each
   improved locally: every point in turn moves to the best cell within MOVE_CELLS grid
   cells when that covers more users, stays 2 d_safe from the others and keeps the plan
   connected (every link within LINK_FRAC R_comm); assigned to the live UAVs with the least
   total travel (Hungarian) from where they are.

Each candidate is scored by a look-ahead: the swarm flown towards it with the twin's own
point-mass dynamics and decision hold for HORIZON_S seconds (users held where they are
now), mean coverage at every decision instant. The best one is flown; the current plan is
kept unless another scores SWITCH_MARGIN more. Because the greedy's plan is scored every
decision, the clairvoyant falls below the greedy only where the look-ahead misjudges
(users move during it, or a later greedy re-plan pays off beyond the horizon).

It is a reference, not a proven bound: no method here is known to be optimal. The reports
take the best reference per episode (learning/eval/references.py).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from scipy.optimize import linear_sum_assignment

from plmarl_sitl.model.coverage import covered_users
from plmarl_sitl.model.demand import cell_centres, demand_cells, demand_map
from plmarl_sitl.model.service import GRID_M, LINK_FRAC, ServiceGrid, grid_counts
from plmarl_sitl.model.vehicle import goto_accel, step_point_mass
from plmarl_sitl.twin.env import CoverageEnv, Observation
from plmarl_sitl.twin.greedy import GreedyController

HORIZON_S = 45  # look-ahead: long enough to fly across a 1 km area and sit there a while
FIRSTS = 4  # fresh greedy plans: the plain one and 3 from other first points
MOVE_CELLS = 2  # local improvement: a point moves at most this many grid cells per step
SWEEPS = 2  # local improvement passes over all points
SWITCH_MARGIN = 1e-3  # mean coverage over the look-ahead a new plan must gain to replace the current one
_CHUNK = 16  # environments per planning block (bounds the (b, V, moves, users) temporaries)


class ClairvoyantController:
    def __init__(self, env: CoverageEnv, grid_m: float = GRID_M, link_frac: float = LINK_FRAC,
                 horizon_s: int = HORIZON_S) -> None:
        self.env = env
        m = env.mission
        self.greedy = GreedyController(env, grid_m, link_frac)
        self.alt, self.r = self.greedy.alt, self.greedy.r
        self.r2 = self.r * self.r
        self.grid_m = grid_m
        self.rows = len(torch.arange(0.0, m.area.north_m + 1e-9, grid_m))
        self.cols = len(torch.arange(0.0, m.area.east_m + 1e-9, grid_m))
        self.cells = self.greedy.cells.double()  # (C, 2), index = row * cols + col
        self.link_ok, self.apart_ok = self.greedy.link_ok, self.greedy.apart_ok
        self.link2 = (link_frac * m.radii.comm_m) ** 2
        self.apart2 = (2.0 * m.radii.safe_m) ** 2
        self.separate_ok = torch.cdist(self.cells, self.cells) >= 2.0 * self.r  # first points of different peaks
        k = math.ceil(self.r / grid_m) + 1
        span = torch.arange(-k, k + 1)
        self.pair_off = torch.cartesian_prod(span, span)  # (P, 2) cells a user may be covered from
        span = torch.arange(-MOVE_CELLS, MOVE_CELLS + 1)
        moves = torch.cartesian_prod(span, span)
        self.moves = moves[(moves != 0).any(-1)]  # (M, 2)
        self.service = ServiceGrid(float(m.area.north_m), float(m.area.east_m), float(m.demand.cell_m), float(self.r),
                                   float(m.radii.comm_m), float(m.radii.safe_m))
        self.map_centres = cell_centres(m.area.north_m, m.area.east_m, m.demand.cell_m, torch.float64)
        self.horizon_s = horizon_s
        self.tau = int(m.timing.decision_every_s)
        self.v_max, self.a_max = float(env.limits.max_speed), float(env.limits.max_accel)
        self.reset()

    def reset(self) -> None:
        self.greedy.reset()
        self.targets: torch.Tensor | None = None  # (B, N, 2) the plan flown
        self.switches = 0  # decisions (summed over environments) at which a new plan replaced the flown one
        self.chosen: dict[str, int] = {}  # candidate kind -> times it was the best

    # ------------------------------------------------------------------ planning
    def _cell_index(self, xy: torch.Tensor) -> torch.Tensor:
        i = torch.clamp(torch.round(xy[..., 0] / self.grid_m).long(), 0, self.rows - 1)
        j = torch.clamp(torch.round(xy[..., 1] / self.grid_m).long(), 0, self.cols - 1)
        return i * self.cols + j

    def covers(self, users: torch.Tensor, pts: torch.Tensor) -> torch.Tensor:
        """users (b, U, 2), pts (b, ..., 2) -> (b, ..., U) bool: the point covers the user."""
        shape = pts.shape
        p = pts.reshape(shape[0], -1, 1, 2)
        d2 = ((users.unsqueeze(1) - p) ** 2).sum(-1)
        return (d2 <= self.r2).reshape(*shape[:-1], users.shape[1])

    def _gain_pairs(self, users: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Every (user, grid cell covering it): cell indices (b, U, P) and validity (b, U, P).
        A user is covered from ~50 cells of 1681, so gains are a scatter over these pairs
        instead of a dense (cells x users) product."""
        i0 = torch.round(users[..., 0] / self.grid_m).long()
        j0 = torch.round(users[..., 1] / self.grid_m).long()
        ii = i0.unsqueeze(-1) + self.pair_off[:, 0]
        jj = j0.unsqueeze(-1) + self.pair_off[:, 1]
        inside = (ii >= 0) & (ii < self.rows) & (jj >= 0) & (jj < self.cols)
        idx = ii.clamp(0, self.rows - 1) * self.cols + jj.clamp(0, self.cols - 1)
        d2 = ((self.cells[idx] - users.unsqueeze(-2)) ** 2).sum(-1)
        return idx, inside & (d2 <= self.r2)

    def greedy_variants(self, users: torch.Tensor, k: int) -> torch.Tensor:
        """(b, V, k) cell indices: greedy plans (connected, 2 d_safe apart) whose first point
        is the best cell (V = 0: the plain greedy) or the next best peaks 2 R apart."""
        b, n_cells = users.shape[0], self.cells.shape[0]
        idx, ok = self._gain_pairs(users)
        okf = ok.to(users.dtype)
        flat = idx.reshape(b, 1, -1).expand(b, FIRSTS, -1).reshape(b * FIRSTS, -1)
        total = torch.zeros(b, n_cells, dtype=users.dtype).scatter_add_(1, idx.reshape(b, -1), okf.reshape(b, -1))
        firsts, free = [], torch.ones(b, n_cells, dtype=torch.bool)
        for _ in range(FIRSTS):
            f = torch.where(free, total, torch.full_like(total, -1.0)).argmax(-1)
            firsts.append(f)
            free = free & self.separate_ok[f]
        first = torch.stack(firsts, -1)  # (b, V)
        unserved = torch.ones(b, FIRSTS, users.shape[1], dtype=users.dtype)
        near = torch.zeros(b, FIRSTS, n_cells, dtype=torch.bool)
        apart = torch.ones_like(near)
        allowed = torch.ones_like(near)
        chosen = []
        for step in range(k):
            if step == 0:
                best = first
            else:
                w = (okf.unsqueeze(1) * unserved.unsqueeze(-1)).reshape(b * FIRSTS, -1)
                gain = torch.zeros(b * FIRSTS, n_cells, dtype=users.dtype).scatter_add_(1, flat, w).view(b, FIRSTS, n_cells)
                best = torch.where(allowed, gain, torch.full_like(gain, -1.0)).argmax(-1)  # ties: lowest index
            chosen.append(best)
            unserved = unserved * ~self.covers(users, self.cells[best])
            near = near | self.link_ok[best]
            apart = apart & self.apart_ok[best]
            allowed = near & apart
        return torch.stack(chosen, -1)

    def _components(self, pts: torch.Tensor, skip: int) -> torch.Tensor:
        """(..., k, k) one-hot component labels of the plan's link graph without point `skip`
        (its row all zero): [.., node, label]."""
        k = pts.shape[-2]
        d2 = ((pts.unsqueeze(-2) - pts.unsqueeze(-3)) ** 2).sum(-1)
        adj = d2 <= self.link2
        adj[..., skip, :] = False
        adj[..., :, skip] = False
        lab = torch.arange(k).expand(pts.shape[:-1]).clone()
        big = torch.full_like(adj, k, dtype=torch.long)
        for _ in range(k):
            new = torch.minimum(lab, torch.where(adj, lab.unsqueeze(-2).expand_as(adj), big).min(-1).values)
            if torch.equal(new, lab):
                break
            lab = new
        onehot = torch.nn.functional.one_hot(lab, k).to(pts.dtype)
        onehot[..., skip, :] = 0.0
        return onehot

    def improve(self, users: torch.Tensor, plan: torch.Tensor) -> torch.Tensor:
        """Local improvement of plans (b, V, k) cell indices: each point in turn moves to the
        best of the cells within MOVE_CELLS that covers more users, 2 d_safe from the others,
        with the plan still connected."""
        k = plan.shape[-1]
        plan = plan.clone()
        pts = self.cells[plan]  # (b, V, k, 2)
        cov = self.covers(users, pts).to(torch.int16)  # (b, V, k, U)
        cnt = cov.sum(2)  # (b, V, U) points covering each user
        for _ in range(SWEEPS):
            moved = False
            for i in range(k):
                ri, rj = plan[..., i] // self.cols, plan[..., i] % self.cols
                ni = ri.unsqueeze(-1) + self.moves[:, 0]
                nj = rj.unsqueeze(-1) + self.moves[:, 1]
                inside = (ni >= 0) & (ni < self.rows) & (nj >= 0) & (nj < self.cols)
                cand = ni.clamp(0, self.rows - 1) * self.cols + nj.clamp(0, self.cols - 1)  # (b, V, M)
                cp = self.cells[cand]
                base = cnt - cov[:, :, i]
                new_cov = ((base.unsqueeze(2) + self.covers(users, cp)) > 0).sum(-1)  # (b, V, M)
                now = (cnt > 0).sum(-1)
                d2 = ((cp.unsqueeze(-2) - pts.unsqueeze(-3)) ** 2).sum(-1)  # (b, V, M, k)
                me = torch.zeros(k, dtype=torch.bool)
                me[i] = True
                apart = ((d2 >= self.apart2) | me).all(-1)
                link = ((d2 <= self.link2) & ~me).to(pts.dtype)
                onehot = self._components(pts, i)  # (b, V, k, k)
                hit = (link @ onehot) > 0  # (b, V, M, labels) the moved point links to that component
                need = onehot.sum(-2) > 0  # (b, V, labels)
                connected = (hit | ~need.unsqueeze(2)).all(-1)
                score = torch.where(inside & apart & connected, new_cov, torch.full_like(new_cov, -1))
                best_score, best = score.max(-1)
                better = best_score > now
                if not bool(better.any()):
                    continue
                moved = True
                to = torch.where(better, cand.gather(-1, best.unsqueeze(-1)).squeeze(-1), plan[..., i])
                plan[..., i] = to
                pts[:, :, i] = self.cells[to]
                cnt = cnt - cov[:, :, i]
                cov[:, :, i] = self.covers(users, pts[:, :, i]).to(torch.int16)
                cnt = cnt + cov[:, :, i]
            if not moved:
                break
        return plan

    def _service_plan(self, users: torch.Tensor, k: int) -> torch.Tensor:
        """(b, 1, k) cell indices: the plan follower's placement on a demand map of the true users."""
        counts = demand_map(users, self.env.mission.area.north_m, self.env.mission.area.east_m,
                            self.env.mission.demand.cell_m)
        rows = demand_cells(counts, self.map_centres).numpy()
        grid_maps = np.stack([grid_counts(r, self.service) for r in rows])
        pts, _ = self.service.place(grid_maps, k)
        return self._cell_index(torch.from_numpy(pts)).unsqueeze(1)

    def _fresh(self) -> torch.Tensor:
        """(B, V + 1, N, 2) fresh plans (greedy variants, service), improved, assigned."""
        env = self.env
        b_all = env.num_envs
        pos = env.pos[..., :2].double()
        out = pos.unsqueeze(1).repeat(1, FIRSTS + 1, 1, 1)  # dead UAVs' targets: where they are
        live_n = env.alive.sum(-1)
        for lo in range(0, b_all, _CHUNK):
            hi = min(b_all, lo + _CHUNK)
            for k in sorted(set(live_n[lo:hi].tolist())):
                if k == 0:
                    continue
                envs = lo + torch.nonzero(live_n[lo:hi] == k).flatten()
                users = env.users.xy[envs].double()
                plans = torch.cat([self.greedy_variants(users, k), self._service_plan(users, k)], 1)
                plans = self.improve(users, plans)
                pts = self.cells[plans]  # (b, V + 1, k, 2)
                for j, e in enumerate(envs.tolist()):
                    live = torch.nonzero(env.alive[e]).flatten()
                    src = pos[e, live]
                    for v in range(pts.shape[1]):
                        cost = torch.cdist(src, pts[j, v]).numpy()
                        rows, cols = linear_sum_assignment(cost)
                        out[e, v, live[torch.from_numpy(rows)]] = pts[j, v, torch.from_numpy(cols)]
        return out

    # ------------------------------------------------------------------ look-ahead
    def _look_ahead(self, targets: torch.Tensor) -> torch.Tensor:
        """(B, K) mean coverage at each decision instant of the next HORIZON_S seconds when
        the swarm flies towards each candidate (B, K, N, 2); users stay where they are."""
        env = self.env
        b, kc, n = targets.shape[:3]
        dt = env.mission.timing.dt_s
        pos = env.pos.unsqueeze(1).expand(b, kc, n, 3).reshape(b * kc, n, 3)
        vel = env.vel.unsqueeze(1).expand(b, kc, n, 3).reshape(b * kc, n, 3)
        alive = env.alive.unsqueeze(1).expand(b, kc, n).reshape(b * kc, n)
        live = alive.unsqueeze(-1)
        goal = torch.cat([targets.to(env.dtype), torch.full((b, kc, n, 1), -self.alt, dtype=env.dtype)], -1).reshape(b * kc, n, 3)
        users = env.users.xy.unsqueeze(1).expand(b, kc, *env.users.xy.shape[1:]).reshape(b * kc, -1, 2)
        left = max(1, min(self.horizon_s, env.horizon - env.t))
        total = torch.zeros(b * kc, dtype=env.dtype)
        decisions = math.ceil(left / self.tau)
        for _ in range(decisions):
            a = goto_accel(pos, vel, goal, self.v_max, self.a_max, time_const=float(self.tau))
            a = torch.where(live, a, torch.zeros_like(a))
            for _ in range(self.tau):
                p2, v2 = step_point_mass(pos, vel, a, dt, env.limits)
                pos = torch.where(live, p2, pos)
                vel = torch.where(live, v2, torch.zeros_like(v2))
            total += covered_users(users, pos, alive, env.radius(-pos[..., 2])).to(env.dtype).mean(-1)
        return (total / decisions).view(b, kc)

    # ------------------------------------------------------------------ control
    KINDS = ("current", "greedy") + tuple(f"greedy-first{v}" for v in range(FIRSTS)) + ("service",)

    def plan_targets(self) -> torch.Tensor:
        """(B, N, 2) the plan chosen at this decision (see the module docstring)."""
        env = self.env
        greedy = self.greedy.plan_targets().double()
        if self.targets is None:
            self.targets = env.pos[..., :2].double().clone()
        cands = torch.cat([self.targets.unsqueeze(1), greedy.unsqueeze(1), self._fresh()], 1)  # (B, K, N, 2)
        score = self._look_ahead(cands)
        best_score, best = score.max(-1)
        best = torch.where(best_score > score[:, 0] + SWITCH_MARGIN, best, torch.zeros_like(best))
        for kind in best.tolist():
            self.chosen[self.KINDS[kind]] = self.chosen.get(self.KINDS[kind], 0) + 1
        self.switches += int((best != 0).sum())
        self.targets = cands[torch.arange(env.num_envs), best]
        return self.targets

    def act(self, obs: Observation) -> torch.Tensor:
        env = self.env
        xy = self.plan_targets().to(env.dtype)
        target = torch.cat([xy, torch.full((env.num_envs, env.n, 1), -self.alt, dtype=env.dtype)], -1)
        return goto_accel(env.pos, env.vel, target, self.v_max, self.a_max, time_const=float(self.tau))
