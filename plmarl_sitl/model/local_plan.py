"""The neighbourhood plan (`coordination: local`): a plan each agent solves over its own region only.

Why (issue 24, part 2): with the team plan (model/service.py) every agent solves the whole
team's greedy placement at every new map: N picks over the whole area, O(N) per map, so an
agent's cost grows with the swarm. The letter's premise is a decision whose cost is O(M) in
the neighbourhood. Here an agent solves, at each new map, a small plan of its own:

1. Its *team* is itself and every teammate it has heard whose predicted position lies in its
   region: its point in the agent's last plan (a UAV of this plan flies to its point and
   stops there), else its held state dead-reckoned at constant velocity for at most
   `PRED_CAP_S`. A teammate out of N_i predicted in
   clear hearing (`SILENT_FRAC` R_comm) is presumed gone and left out (`predicted_team`).
2. Its *region* is a window of map cells: the square tile of side `REGION_FRAC` R_comm it is
   on (tiles fixed on the map) and the tiles around it, 3 x 3 (`window`). Agents on one tile
   share their window, so with the same knowledge they solve the same plan.
3. `solve`: greedy service points in the window, one per team member at most (each on the
   cell centre whose coverage disk holds the most still-unserved users of the window, at least
   2 d_safe from the earlier picks; then moved to the users' centroid it serves), and the
   points assigned to the team by least total travel (the Hungarian of model/assignment.py)
   from those positions, so agents that made the same last plan keep agreeing. The agent flies to its own point.
4. An agent the region leaves without a point (more neighbours than demand around it) heads
   for the nearest demand cell outside its region: coverage the neighbourhood does not reach.

Cost: O(window cells x picks) per new map and O(1) per decision, whatever N and the area
(the window is at most (3 REGION_FRAC R_comm / cell_m)^2 cells, the picks at most 1 + |N_i|); the
map itself is read once per map (its nonzero cells), as every coordination must.

What it gives up against the team plan: agreement. Neighbours solve over different regions
and teams, so two can take the same cluster, and demand farther than the region from every
agent is found only by the agents the step-4 fallback sends out. docs/RESULTS.md
("Session 13") measures the coverage it costs. Twin (learning/nn/local_targets.py) and the
deployed agent (deploy/agent/local_plan.py) run this same class on the same inputs.
"""

from __future__ import annotations

import math

import numpy as np

from plmarl_sitl.model.assignment import linear_sum_assignment
from plmarl_sitl.model.demand import grid_shape
from plmarl_sitl.model.service import launch_line

REGION_FRAC = 2.0  # the side of a region's tile, x R_comm; the window is 3 x 3 tiles
PRED_CAP_S = 10.0  # a neighbour's held state is dead-reckoned for at most this long
SILENT_FRAC = 0.8  # a teammate out of N_i predicted this close (x R_comm) is presumed gone (model/gossip.py's range)


class LocalPlan:
    """One agent's neighbourhood plan on the mission's demand grid (area, cells, coverage
    radius, R_comm, d_safe): `set_map` at each new map, `solve` for its point."""

    def __init__(self, area_n: float, area_e: float, cell_m: float, cover_r: float, comm_m: float, safe_m: float) -> None:
        self.cell_m = float(cell_m)
        self.rows, self.cols = grid_shape(area_n, area_e, cell_m)
        self.comm_m = float(comm_m)
        self.region_m = REGION_FRAC * self.comm_m
        self.reach = int(self.region_m // cell_m)  # window half side, cells
        r = int(cover_r // cell_m)
        di, dj = np.meshgrid(np.arange(-r, r + 1), np.arange(-r, r + 1), indexing="ij")
        keep = (di * di + dj * dj) * cell_m * cell_m <= cover_r * cover_r  # a cell centre within the radius
        self.disk = (di[keep], dj[keep])
        s = int(math.ceil(2.0 * safe_m / cell_m))
        si, sj = np.meshgrid(np.arange(-s, s + 1), np.arange(-s, s + 1), indexing="ij")
        close = (si * si + sj * sj) * cell_m * cell_m < (2.0 * safe_m) ** 2  # closer than 2 d_safe: no second pick
        self.close = (si[close], sj[close])
        self.counts: np.ndarray | None = None  # (rows, cols) users per cell of the current map
        self.nonzero: np.ndarray | None = None  # (Z, 2) cell indices with users (the fallback's targets)

    def set_map(self, cells: np.ndarray) -> None:
        """A new map: rows cells (R, 3) [centre north, centre east, count] (a message's nonzero
        cells, or the whole map), onto the grid as `model/service.py::grid_counts` does."""
        cells = np.asarray(cells, dtype=np.float64)
        r = np.clip(np.floor(cells[:, 0] / self.cell_m), 0, self.rows - 1).astype(np.int64)
        c = np.clip(np.floor(cells[:, 1] / self.cell_m), 0, self.cols - 1).astype(np.int64)
        counts = np.zeros(self.rows * self.cols)
        np.add.at(counts, r * self.cols + c, cells[:, 2])
        self.counts = counts.reshape(self.rows, self.cols)
        self.nonzero = np.argwhere(self.counts > 0)

    def window(self, xy: np.ndarray) -> tuple[int, int, int, int]:
        """The region of an agent at xy: its tile (side `reach` cells, fixed on the map) and one
        tile around it, in cells [i0, i1) x [j0, j1), clipped to the area. Agents on one tile
        share their window, so with the same knowledge they solve the same plan."""
        ti, tj = int(xy[0] // (self.reach * self.cell_m)), int(xy[1] // (self.reach * self.cell_m))
        i0, j0 = max(0, (ti - 1) * self.reach), max(0, (tj - 1) * self.reach)
        return i0, min(self.rows, (ti + 2) * self.reach), j0, min(self.cols, (tj + 2) * self.reach)

    def team(self, me: int, ego_xy: np.ndarray, held: np.ndarray, t_rx: np.ndarray, mask: np.ndarray,
             t: float, memory: dict[int, np.ndarray], launch: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """`predicted_team` with this plan's R_comm and window."""
        i0, i1, j0, j1 = self.window(ego_xy)
        return predicted_team(me, ego_xy, held, t_rx, mask, t, self.comm_m,
                              (i0 * self.cell_m, i1 * self.cell_m, j0 * self.cell_m, j1 * self.cell_m), memory, launch)

    def solve(self, me_id: int, team: tuple[np.ndarray, np.ndarray], memory: dict[int, np.ndarray]) -> np.ndarray | None:
        """(2,) north, east of the agent's point; team (ids (k,), xy (k, 2) float64): the agent
        me_id and its teammates' predicted positions (`team`). None: no demand anywhere (hold).

        The team's positions are where each member is headed by the agent's last plan
        (`memory`: identity -> point, updated here; `team`), so every agent of a window that
        made the same last plan assigns alike, whatever it believes of the teammates in
        transit (as the team plan keeps each identity on the successor of its point)."""
        assert self.counts is not None
        ids, team_xy = team
        mine_row = int(np.flatnonzero(ids == me_id)[0])
        me = team_xy[mine_row]
        i0, i1, j0, j1 = self.window(me)
        if i0 >= i1 or j0 >= j1:  # outside the area: the nearest demand
            return self._fallback(me, None)
        w = self.counts[i0:i1, j0:j1].copy()
        h, wd = w.shape
        di, dj = self.disk
        gain = self._gains(w)  # a cell too close to a pick is -inf for good
        picks = []
        for _ in range(len(team_xy)):
            best = int(gain.argmax())  # ties: the lowest cell index
            if gain.flat[best] <= 0.0:
                break
            pi, pj = divmod(best, wd)
            ri, rj = pi + di, pj + dj
            ok = (ri >= 0) & (ri < h) & (rj >= 0) & (rj < wd)
            ri, rj = ri[ok], rj[ok]
            x = w[ri, rj]
            lit = x > 0
            ri, rj, x = ri[lit], rj[lit], x[lit]
            w[ri, rj] = 0.0
            # the users' centroid it serves (cell centres weighted by their users)
            picks.append(((np.dot(x, ri + i0 + 0.5)) / x.sum() * self.cell_m, (np.dot(x, rj + j0 + 0.5)) / x.sum() * self.cell_m))
            # every candidate that covered a newly served cell loses its users
            gi, gj = (ri[:, None] - di[None]).ravel(), (rj[:, None] - dj[None]).ravel()
            gx = np.repeat(x, len(di))
            ok = (gi >= 0) & (gi < h) & (gj >= 0) & (gj < wd)
            np.subtract.at(gain, (gi[ok], gj[ok]), gx[ok])
            si, sj = pi + self.close[0], pj + self.close[1]
            ok = (si >= 0) & (si < h) & (sj >= 0) & (sj < wd)
            gain[si[ok], sj[ok]] = -np.inf
        if picks:
            pts = np.asarray(picks)
            cost = np.sqrt(((team_xy[:, None, :] - pts[None]) ** 2).sum(-1))
            rows, cols = linear_sum_assignment(cost)
            for j in ids:
                memory.pop(int(j), None)
            for r, c in zip(rows, cols, strict=True):
                memory[int(ids[r])] = pts[c]
            mine = cols[rows == mine_row]
            if len(mine):
                return pts[int(mine[0])]
        else:
            for j in ids:
                memory.pop(int(j), None)
        return self._fallback(me, (i0, i1, j0, j1))

    def _gains(self, w: np.ndarray) -> np.ndarray:
        """Users within the coverage disk of each window cell (a sum of shifted copies)."""
        h, wd = w.shape
        di, dj = self.disk
        r = int(max(np.abs(di).max(), np.abs(dj).max()))
        pad = np.zeros((h + 2 * r, wd + 2 * r))
        pad[r:r + h, r:r + wd] = w
        gain = np.zeros((h, wd))
        for a, b in zip(di, dj, strict=True):
            gain += pad[r + a:r + a + h, r + b:r + b + wd]
        return gain

    def _fallback(self, me: np.ndarray, window: tuple[int, int, int, int] | None) -> np.ndarray | None:
        """The nearest cell with users outside the window (or anywhere without one); None if none."""
        nz = self.nonzero
        if window is not None and len(nz):
            i0, i1, j0, j1 = window
            nz = nz[~((nz[:, 0] >= i0) & (nz[:, 0] < i1) & (nz[:, 1] >= j0) & (nz[:, 1] < j1))]
        if nz is None or not len(nz):
            return None
        xy = (nz + 0.5) * self.cell_m
        d2 = ((xy - me) ** 2).sum(-1)
        return xy[int(d2.argmin())]


def heard_launch_line(ego_xy: np.ndarray, held_xy: np.ndarray, heard: np.ndarray, me: int,
                      nominal: np.ndarray | None = None) -> np.ndarray:
    """(n, 2) the team's launch line fitted through the agent (ego_xy) and the teammates it heard
    at the first instant (heard (n,) bool, at held_xy (n, 2)), or the mission's line `nominal` when
    they all lie on it (`launch_line`): `learning/nn/plan.py::heard_launch`, here so the twin's and
    the agent's local plans share it without importing the team plan's module."""
    ids = [me] + [j for j in range(len(heard)) if heard[j] and j != me]
    pos = np.stack([np.asarray(ego_xy, dtype=np.float64)] + [held_xy[j] for j in ids[1:]])
    return launch_line(np.asarray(ids), pos, len(heard), nominal)


def predicted_team(me: int, ego_xy: np.ndarray, held: np.ndarray, t_rx: np.ndarray, mask: np.ndarray, t: float,
                   comm_m: float, window: tuple[float, float, float, float], memory: dict[int, np.ndarray],
                   launch: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(ids (k,), xy (k, 2) float64), in identity order: the agent me at ego_xy (2,), every other
    identity it has heard (t_rx (n,) >= 0) or planned for (memory) (mask (n,) N_i, the agent itself excluded) at its
    point of the agent's last plan (memory: identity -> point; a UAV of this plan flies there
    and stops), else at its held state held (n, 6) [pos NED, vel NED] dead-reckoned from t_rx
    to t for at most PRED_CAP_S; kept if that lies in the window (north0, north1, east0, east1) metres. An
    identity out of N_i predicted within SILENT_FRAC R_comm should be heard and is not:
    presumed gone (failed), it is left out, so its demand is taken over. launch (n, 2) (the
    first plan only): the team's launch line fitted through those heard and rounded
    (`model/service.py::launch_line`): every identity on it is taken to be there, itself
    included, so agents whose fits agree assign the first plan alike, ties included (a
    lattice map has exact ties that held positions' last bits would break differently)."""
    known = t_rx >= 0
    known[[j for j in memory if j != me]] = True  # in its last plan (placed from the launch line, say), heard or not
    heard = np.flatnonzero(known)
    age = np.clip(t - t_rx[heard], 0.0, PRED_CAP_S)[:, None]
    xy = held[heard, :2] + held[heard, 3:5] * age
    for r, j in enumerate(heard.tolist()):  # headed to its point of the agent's last plan, and stopped there
        if j in memory:
            xy[r] = memory[j]
    d = xy - np.asarray(ego_xy, dtype=np.float64)
    n0, n1, e0, e1 = window
    inside = (xy[:, 0] >= n0) & (xy[:, 0] < n1) & (xy[:, 1] >= e0) & (xy[:, 1] < e1)
    silent = ~mask[heard] & ((d * d).sum(-1) <= (SILENT_FRAC * comm_m) ** 2)
    keep = inside & ~silent
    ids = np.concatenate([[me], heard[keep]]).astype(np.int64)
    xy = np.concatenate([np.asarray(ego_xy, dtype=np.float64)[None], xy[keep]], 0)
    if launch is not None:  # the first plan: the whole team on the fitted launch line (rounded), as the team plan
        ids = np.flatnonzero((launch[:, 0] >= n0) & (launch[:, 0] < n1) & (launch[:, 1] >= e0) & (launch[:, 1] < e1))
        ids = np.union1d(ids, [me]).astype(np.int64)
        xy = launch[ids].copy()
    order = np.argsort(ids, kind="stable")  # identity order: agents that know the same build the same matrix
    return ids[order], xy[order]


__all__ = ["PRED_CAP_S", "REGION_FRAC", "SILENT_FRAC", "LocalPlan", "heard_launch_line", "predicted_team"]
