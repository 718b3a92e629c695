"""The failure flag f of input version 2, as the twin computes it, from drops booked late.

The twin (`learning.nn.belief.FailureFlags`) sees the drops of signalling instant t at its
first decision d >= t and sets f, latched, when a dropped neighbour's belief at d is still
within R_comm of the agent at d (`model.signalling.silent_in_range`: "predicted in range,
yet silent"). An agent books an instant's misses a grace period after it (a late update
is not a miss), often after decision d has been made; judged then, with a later belief, a
neighbour flying away would be believed out of range more often than in the twin. So the
agent keeps the positions of its last decisions and judges each drop with those of the
decision the twin would have used. Its f therefore equals the twin's from the decision
after the booking on (tests/deploy/test_twin_replay.py); only the decision made before
the booking can miss it.
"""

from __future__ import annotations

import torch

from plmarl_sitl.deploy.agent.clock import next_multiple
from plmarl_sitl.model.signalling import silent_in_range

KEEP_S = 120  # decisions kept: longer than any grace period (at most T_up / 2)


class FailureFlag:
    def __init__(self, n: int, tau: int, comm_m: float) -> None:
        self.n, self.tau, self.comm_m = n, tau, comm_m
        self.value = False
        self.decided: dict[int, tuple[torch.Tensor, torch.Tensor]] = {}  # decision second -> (belief pos (N, 3), ego pos (3,))
        self.pending: dict[int, list[int]] = {}  # decision second -> neighbours it will see dropped

    def _judge(self, dropped: list[int], belief_pos: torch.Tensor, ego_pos: torch.Tensor) -> None:
        mask = torch.zeros(self.n, dtype=torch.bool)
        mask[dropped] = True
        self.value = self.value or bool(silent_in_range(mask, belief_pos, ego_pos, self.comm_m))

    def on_dropped(self, instant: int, dropped: list[int]) -> None:
        """Neighbours that signalling instant `instant` dropped from N_i (booked now)."""
        d = next_multiple(instant, self.tau)  # the twin's decision that sees this drop
        if d in self.decided:
            self._judge(dropped, *self.decided[d])
        else:
            self.pending.setdefault(d, []).extend(dropped)

    def on_decision(self, k: int, belief: torch.Tensor, ego: torch.Tensor) -> bool:
        """f for decision k, with this decision's beliefs (N, 6) and own state (6,)."""
        pos, own = belief[:, 0:3].clone(), ego[0:3].clone()
        for d in [d for d in self.pending if d <= k]:
            self._judge(self.pending.pop(d), pos, own)
        self.decided[k] = (pos, own)
        for d in [d for d in self.decided if d < k - KEEP_S]:
            del self.decided[d]
        return self.value
