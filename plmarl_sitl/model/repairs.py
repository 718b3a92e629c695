"""Local failure repairs (mission key `failure_replan: local`, issue 24): how a copy of the team
plan (`service.TeamPlans`) is mended when it learns that teammates failed.

Why. Under sparse signalling (T_up 50) the survivors learn a failure at different instants: each
first declares the teammate *it* expected to hear, re-plans, and flies to its new point before
the next instant tells the others. A full re-solve of the plan for each copy's failed set puts
survivors on points of different copies' plans, and the swarm splits (docs/RESULTS.md, session
24, "what splits the survivors' heard graph"). A local repair changes little: each failed
identity's point is dropped and at most MOVERS_K of *its neighbours* (the survivors within
R_link of it in the first plan) move. The survivors who detect a failure first-hand are its
neighbours, so a copy that knows of one failure moves only UAVs that know of it too, and
every other survivor keeps the point the uninformed copies also give it.

Only on station. A repair keeps the first plan, which is right while the survivors fly it. A
failure in transit (the survivors still far from their points) is re-solved: the re-solve assigns
the survivors by their predicted positions, and a repair would keep an assignment made for a
swarm that has lost a member on the way (session 25: local repairs alone lost 0.008-0.012 there).
So a copy repairs only if every survivor's predicted position at the failure's epoch is within
STATION_M of its point in the first plan; otherwise it re-solves, as `failure_replan: resolve`
does. This is the default since session 27 (docs/RESULTS.md).

Everything a repair reads is common knowledge (the first plan followed through the maps up to
the failure's epoch, the failed set, the map, the predicted positions), so copies that know the
same failures hold the same plan. Measured in the twin on tuning seeds 19-22 (session 24),
23-26 (session 25) and 34-36 (session 27): docs/RESULTS.md.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from plmarl_sitl.model.service import ServiceGrid, assign

MOVERS_K = 2  # survivors a repair may move: each mover is a UAV leaving a served spot
REPAIR_MARGIN = 1.0  # users: an option with fewer movers is taken if it serves within this of the best
# A repair only while every survivor is predicted this close to its first-plan point: 15 s of
# flight at the 20 m/s speed limit. In the failure-in-transit family (1 km transit) the survivors
# are 359-1029 m away at the failure; on station the largest seen was 269 m (tuning seed 34).
STATION_M = 300.0


class Option(NamedTuple):
    """A kept plan: points (m, 2), the rows moved (in the order moved), users served, and
    whether it is feasible (one link component, every pair 2 d_safe apart)."""

    points: np.ndarray
    movers: list[int]
    served: float
    feasible: bool


def link_components(pts: np.ndarray, link_m: float) -> np.ndarray:
    """(m,) the component label (its lowest member's row) of each point (m, 2) in the graph
    'within link_m' (as `ServiceGrid.place` keeps a plan connected)."""
    m = len(pts)
    near = np.sqrt(((pts[:, None] - pts[None]) ** 2).sum(-1)) <= link_m
    label = np.arange(m)
    for _ in range(m):
        label = np.where(near, label[None, :], m).min(-1)
    return label


def keep_and_move(grid: ServiceGrid, counts: np.ndarray, old: np.ndarray, k_max: int,
                  rows: np.ndarray | None = None) -> list[Option]:
    """The plans kept from the points old (m, 2, on candidates) on one map counts (K,) with
    0..k_max of the rows moved, one Option each. Each step moves the row, to the candidate,
    that leaves the fewest link components, then serves the most users with the others fixed,
    2 d_safe from them; ties to the lowest row, then candidate. It stops early when the best
    move is a row's own point. rows: the rows that may move (None: all)."""
    w = grid.sub_weights(counts)
    pts, movers, out = old.astype(np.float64).copy(), [], []
    for step in range(k_max + 1):
        served = float(grid.served(counts[None], pts[None])[0])
        d = np.sqrt(((pts[:, None] - pts[None]) ** 2).sum(-1))
        apart = bool((d[~np.eye(len(pts), dtype=bool)] >= grid.apart_m).all())
        out.append(Option(pts.copy(), list(movers), served, apart and bool((link_components(pts, grid.link_m) == 0).all())))
        if step == k_max:
            break
        best = None
        for r in range(len(pts)):
            if r in movers or (rows is not None and r not in rows):
                continue
            others = np.delete(pts, r, 0)
            hit = grid.covered(others)
            gain = grid.weight_gains(np.where(hit, 0.0, w))  # (C,) sub-point units
            dist = np.sqrt((grid.cand_n[:, None] - others[:, 0]) ** 2 + (grid.cand_e[:, None] - others[:, 1]) ** 2)  # (C, m-1)
            label = link_components(others, grid.link_m)
            touch = [(dist[:, label == lab] <= grid.link_m).any(-1) for lab in np.unique(label)]
            comps = len(touch) + 1 - np.sum(touch, 0)  # components with the candidate added
            spaced = (dist >= grid.apart_m).all(-1)
            total = (w * hit).sum() + gain  # users served with the candidate, sub-point units
            key = np.where(spaced, comps * (w.sum() + 1.0) - total, np.inf)  # fewest components, then most served
            cand = int(key.argmin())  # ties: the lowest candidate
            if np.isfinite(key[cand]) and (best is None or key[cand] < best[0]):
                best = (key[cand], r, cand)
        if best is None:
            break
        _, r, cand = best
        if np.array_equal(grid.cands[cand], pts[r]):  # its own point is its best: nobody needs to move
            break
        pts[r] = grid.cands[cand]
        movers.append(r)
    return out


def repair(grid: ServiceGrid, counts: np.ndarray, pts: np.ndarray, ident: np.ndarray, f: int,
           src: np.ndarray, allowed: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[int]] | None:
    """The plan pts (m, 2) of identities ident (m,) (row i: identity ident[i]) without identity
    f, on the map counts (K,): its survivors' points with up to MOVERS_K of the rows `allowed`
    (rows of pts) re-placed (`keep_and_move`), the feasible option with the fewest movers that
    serves within REPAIR_MARGIN of the best feasible one. The movers take that option's new
    points by least travel from src (n, 2) (every identity's predicted position).
    (points (m-1, 2), identities (m-1,), the movers' identities), or None if no option is feasible."""
    keep = ident != f
    old, who = pts[keep], ident[keep]
    rows = np.flatnonzero(np.isin(np.flatnonzero(keep), allowed))
    options = [o for o in keep_and_move(grid, counts, old, MOVERS_K, rows) if o.feasible]
    if not options:
        return None
    best = max(o.served for o in options)
    new, movers, _, _ = next(o for o in options if o.served >= best - REPAIR_MARGIN)
    new = new.copy()
    if len(movers) > 1:  # the movers take the new points by least travel
        mv = np.asarray(movers)
        new[mv] = new[mv][assign(src[who[mv]], new[mv])]
    return new, who, [int(who[r]) for r in movers]


def on_station(first: np.ndarray, failed: np.ndarray, src: np.ndarray) -> bool:
    """Every survivor's predicted position src (n, 2) within STATION_M of its point in the
    first plan first (n, 2): the swarm flies that plan, so mending it is right."""
    live = ~failed
    return bool((((src[live] - first[live]) ** 2).sum(-1) <= STATION_M**2).all())


def local_repairs(grid: ServiceGrid, counts: np.ndarray, first: np.ndarray, failed: np.ndarray,
                  src: np.ndarray) -> np.ndarray | None:
    """The first plan first (n, 2) (row j: identity j's point, followed through the maps up to
    the epoch) repaired for each identity of failed (n,) bool, in increasing identity order, on
    the map counts (K,): each repair moves only that identity's neighbours, the survivors within
    R_link of it in `first`. src (n, 2): every identity's predicted position at the epoch.
    (m, 2) the survivors' points in identity order, or None (a failed identity without a live
    neighbour, a repair without a feasible option, or a survivor more than STATION_M from its
    point in `first`: the caller re-solves the whole plan)."""
    if not on_station(first, failed, src):
        return None
    pts, ident = first.copy(), np.arange(len(first))
    for f in np.flatnonzero(failed):
        near = np.sqrt(((first - first[f]) ** 2).sum(-1)) <= grid.link_m
        neighbours = np.flatnonzero(near & ~failed)
        allowed = np.flatnonzero(np.isin(ident, neighbours))
        if allowed.size == 0:
            return None
        out = repair(grid, counts, pts, ident, int(f), src, allowed)
        if out is None:
            return None
        pts, ident, _ = out
    return pts
