"""What an agent holds of its neighbours: the deployed twin of `world.signalling.Holdings`.

Slots are indexed by UAV id (N slots, the agent's own slot always masked), exactly the
twin's layout, so the same tracker and policy see the same tensors. The rules are the
twin's: a state received for instant t replaces the held one (t_rx = t); at every
signalling instant each neighbour either delivered (missed = 0) or missed one more;
j is in N_i while fewer than `drop_after_missed` instants in a row were missed; the
failure state f becomes true (and stays) once a neighbour that was in N_i is dropped.

Over a real network an update can arrive after its instant. Delivery counts when it
arrives (`on_state` resets the miss count at once, as the twin does at the instant), and
a miss is only booked when the agent closes the instant (`close_instant`), which it does
a grace period after the instant, so a late update is not a miss.
"""

from __future__ import annotations

import torch

from plmarl_sitl.model.gossip import NOTHING, Knowledge, Known
from plmarl_sitl.model.signalling import NEVER


class NeighbourTable:
    def __init__(self, n: int, me: int, drop_after_missed: int) -> None:
        self.n, self.me, self.drop = n, me, drop_after_missed
        self.state = torch.zeros(n, 6)
        self.t_rx = torch.full((n,), NEVER)
        self.missed = [0] * n
        self.ever = [False] * n
        self.lost = False
        self.dropped: list[int] = []  # ids dropped, in order (for logs and tests)
        self.closed: int | None = None  # the newest signalling instant whose misses are booked
        self.knowledge = Knowledge(me)  # failures known, merged from the states received (model/gossip.py)
        # N_i as a tensor, made again only after a state or an instant changed it: every
        # mission second reads it, and most seconds neither arrives.
        self._mask: torch.Tensor | None = None

    def on_state(self, j: int, t_s: float, state: tuple[float, ...], known: Known = NOTHING) -> bool:
        """Take a received state and the sender's knowledge (failed set, epoch, incarnations)
        it carries; False if it is not newer than what we hold."""
        if j == self.me or not 0 <= j < self.n or t_s < float(self.t_rx[j]):
            return False
        self.knowledge.learn(t_s, known, j)
        self.state[j] = torch.tensor(state, dtype=torch.float32)
        self.t_rx[j] = t_s
        self.ever[j] = True
        self.missed[j] = 0  # delivered for instant t_s
        self._mask = None
        return True

    def in_set(self, j: int) -> bool:
        return j != self.me and self.ever[j] and self.missed[j] < self.drop

    def mask(self) -> torch.Tensor:
        """(n,) bool N_i (shared until the table changes: read it, do not write it)."""
        if self._mask is None:
            self._mask = torch.tensor([self.in_set(j) for j in range(self.n)], dtype=torch.bool)
        return self._mask

    def close_instant(self, t_s: float) -> list[int]:
        """Account for signalling instant t; returns the neighbours dropped by it."""
        newly = []
        self._mask = None
        self.closed = int(t_s) if self.closed is None else max(self.closed, int(t_s))
        for j in range(self.n):
            if j == self.me:
                continue
            if float(self.t_rx[j]) >= t_s:
                continue  # delivered (on_state already reset the count)
            was = self.in_set(j)
            self.missed[j] += 1
            if was and not self.in_set(j):
                newly.append(j)
        if newly:
            self.lost = True
            self.dropped.extend(newly)
        return newly
