"""Prototype (twin only, not product code): a failure re-plan in which the survivors that
cannot know the failure yet keep their points (issue 24, T_up 50 2-of-6 gap).

`TeamPlans.replan` re-places one point per survivor and assigns them all afresh, so a
survivor that learns the failure one or two signalling instants later (one hop per T_up)
is meanwhile at a point the knowing survivors' plan no longer counts on. Here a step
instead pins every survivor the channel could not have told (predicted, at the step's
epoch, farther than `--reach` x R_comm from every identity newly declared in the step) to
its point in the copy's plan, and re-places only the others greedily around the pinned
points. The pinned set is a function of the plan-aware prediction and the declarations
(common knowledge), so copies that know the same still hold the same plan.

    PYTHONPATH=. python docs/results/issue24/session14/pinned_replan.py [--reach 1.0] -- <bench.replan args>
"""

from __future__ import annotations

import sys

import numpy as np

from plmarl_sitl.bench import replan as bench
from plmarl_sitl.model import service
from plmarl_sitl.model.service import LINK_FRAC, ROUND_M, TeamPlans, assign

REACH = 1.0  # x R_comm: a survivor within this of a newly declared identity may have declared it
ORIGINAL = TeamPlans.replan
STATS = {"pinned_steps": 0, "fresh_steps": 0}


def place_around(grid: service.ServiceGrid, counts: np.ndarray, pinned: np.ndarray, m: int) -> np.ndarray:
    """(m, 2) greedy points on one map counts (K,), given the points pinned (p, 2) already held:
    the same gain, link and spacing tests as `ServiceGrid.place`, dense (a prototype)."""
    w = grid._weights(counts[None])[0].copy()
    c = len(grid.cands)
    pair_cand = np.repeat(np.arange(c), np.diff(grid.cover_ptr))
    near = np.zeros(c, dtype=bool)
    apart = np.ones(c, dtype=bool)

    def take(idx: int) -> None:
        nonlocal near, apart
        w[grid.cover_idx[grid.cover_ptr[idx]:grid.cover_ptr[idx + 1]]] = 0.0
        d = np.sqrt((grid.cand_n - grid.cand_n[idx]) ** 2 + (grid.cand_e - grid.cand_e[idx]) ** 2)
        near |= d <= grid.link_m
        apart &= d >= grid.apart_m

    for p in grid._candidate_index(pinned):
        take(int(p))
    out = []
    for _ in range(m):
        gain = np.bincount(pair_cand, weights=w[grid.cover_idx], minlength=c)
        best = int(np.where(near & apart, gain, -1.0).argmax())
        out.append(best)
        take(best)
    return grid.cands[np.asarray(out)]


def pinned_replan(self: TeamPlans, b: int, a: int, failed: np.ndarray, epoch: int, sources: np.ndarray | None = None) -> None:
    new = failed & ~self.failed[b, a]
    alive = np.flatnonzero(~failed)
    live_slots = self.slot[b, a, alive]
    if sources is not None or not new.any() or alive.size == 0 or (live_slots < 0).any():
        STATS["fresh_steps"] += 1
        return ORIGINAL(self, b, a, failed, epoch, sources)
    comm = self.grid.link_m / LINK_FRAC
    src = self.motion.sources(b, a, epoch, alive)
    gone = self.motion.sources(b, a, epoch, np.flatnonzero(new))
    d = np.sqrt(((src[:, None] - gone[None]) ** 2).sum(-1)).min(1)
    free = d <= REACH * comm
    if free.all() or not free.any():
        STATS["fresh_steps"] += 1
        return ORIGINAL(self, b, a, failed, epoch, sources)
    STATS["pinned_steps"] += 1
    self.before.setdefault((b, a), []).append((self.failed[b, a].copy(), int(self.epoch[b, a]), self.since[b, a].copy(),
                                               self.points[b, a].copy(), self.slot[b, a].copy(), self.motion.t, int(epoch)))
    self.steps.setdefault((b, a), []).append((failed.copy(), int(epoch)))
    self.since[b, a] = np.where(failed, np.where(self.since[b, a] > 0, self.since[b, a], epoch), 0)
    old = self.points[b, a].copy()
    held = old[live_slots[~free]]  # the pinned survivors' points
    counts = [cnt for s, cnt in self.maps if s <= epoch] or [self.maps[0][1]]
    fresh = place_around(self.grid, counts[-1][b], held, int(free.sum()))
    pts = np.concatenate([held, fresh])
    self.points[b, a] = np.nan
    self.points[b, a, : len(alive)] = pts
    self.slot[b, a] = -1
    self.slot[b, a, alive[~free]] = np.arange(len(held))
    fsrc = np.round(src[free] / ROUND_M) * ROUND_M
    self.slot[b, a, alive[free]] = len(held) + assign(fsrc, fresh)
    self.failed[b, a], self.epoch[b, a] = failed, epoch
    self._follow_maps(b, a, epoch)
    self.motion.replay(b, a, epoch, self.all_targets()[b, a])


def main(argv: list[str]) -> int:
    global REACH
    if "--reach" in argv:
        i = argv.index("--reach")
        REACH = float(argv[i + 1])
        del argv[i : i + 2]
    if argv and argv[0] == "--":
        argv = argv[1:]
    TeamPlans.replan = pinned_replan
    print(f"pinned re-plan prototype, reach {REACH} x R_comm", flush=True)
    rc = bench.main(argv)
    print(STATS, flush=True)
    return rc


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
