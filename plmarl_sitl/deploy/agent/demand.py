"""The user-density maps an agent has received, and the one a decision uses.

Maps arrive on `plmarl/<swarm>/demand` (deploy/mqtt/demand.py); a newer map_seq wins, an
older or repeated one is counted `stale` and dropped. A decision at second k uses the
newest map whose snapshot is not after k, as `model.demand.demand_cells` rows (the twin's
function; empty cells are simply absent), or None before the first map.

When a map is due (`model.demand.is_map_instant`: the seconds the twin refreshes its map),
the decision waits for it, bounded like a signalling instant (`MissionClock.second_due`);
the SITL world publishes each map a map period ahead, so the wait is a guard against a
late bus, not the rule. A decision made at a map instant without that map counts as `late`.
Before any map has arrived only the first decision waits (is there a publisher at all?).
"""

from __future__ import annotations

import collections
import logging

import torch

from plmarl_sitl.deploy.mqtt.demand import DemandMsg, seq_newer
from plmarl_sitl.mission import Mission
from plmarl_sitl.model.demand import cell_centres, demand_cells, grid_shape, is_map_instant

log = logging.getLogger("plmarl.agent")

EPS = 1e-6


class DemandMaps:
    def __init__(self, mission: Mission, topic: str) -> None:
        m = mission
        self.topic = topic  # for the warning when nobody publishes
        self.refresh_s, self.tau = m.demand.refresh_s, m.timing.decision_every_s
        # The mission's own grid, so a map on it gets exactly the twin's cell centres (the
        # message carries cell_m as float32).
        self.cell_m = float(m.demand.cell_m)
        self.grid = grid_shape(m.area.north_m, m.area.east_m, self.cell_m)
        self.centres = cell_centres(m.area.north_m, m.area.east_m, self.cell_m)
        self.maps: collections.deque[tuple[float, int, torch.Tensor]] = collections.deque(maxlen=4)  # (t_s, seq, cells)
        self.accepted = self.stale = self.late = 0
        self.warned = False

    def on_message(self, msg: DemandMsg) -> bool:
        """Take a decoded map; False (counted stale) unless it is newer than the last one."""
        if self.maps and not seq_newer(msg.map_seq, self.maps[-1][1]):
            self.stale += 1
            return False
        self.maps.append((msg.t_s, msg.map_seq, self.cells(msg)))
        self.accepted += 1
        return True

    def cells(self, msg: DemandMsg) -> torch.Tensor:
        """(K, 3) [centre north, centre east, count] of the message's nonzero cells."""
        idx = torch.tensor([i for i, _ in msg.cells], dtype=torch.long)
        counts = torch.tensor([c for _, c in msg.cells], dtype=torch.float32)
        if (msg.rows, msg.cols) == self.grid and msg.cell_m == float(torch.tensor(self.cell_m, dtype=torch.float32)):
            centres = self.centres
        else:  # another grid than the mission's: still a valid map
            centres = cell_centres(msg.rows * msg.cell_m, msg.cols * msg.cell_m, msg.cell_m)
        return demand_cells(counts, centres[idx])

    def awaiting(self, k: int) -> bool:
        """Decision k should still wait for a map: one is due at k and has not arrived."""
        if not is_map_instant(k, self.refresh_s, self.tau):
            return False
        if self.maps:
            return self.maps[-1][0] < k - EPS
        return not self.warned  # no map yet: wait once, to learn whether anyone publishes

    def for_decision(self, k: int) -> tuple[float, torch.Tensor] | None:
        """(snapshot time, cells) of the newest map not after second k; None before any."""
        got = next(((t, c) for t, _, c in reversed(self.maps) if t <= k + EPS), None)
        if is_map_instant(k, self.refresh_s, self.tau) and (got is None or got[0] < k - EPS):
            if self.maps:
                self.late += 1
            elif not self.warned:
                self.warned = True
                log.warning("no demand publisher on %s: flying without a demand map", self.topic)
        return got

    def counters(self) -> dict[str, int]:
        return {"accepted": self.accepted, "stale": self.stale, "late": self.late}
