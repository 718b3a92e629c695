"""What the live map shows of a running mission, from what the monitor knows: the UAV
rows of the world's metrics, plus the mission and its seed. The users are replayed (they
depend only on the mission and the seed, `report_map.replay_users`), one step per mission
second as the world steps them; the links are the world's (`links.u2u_links`)."""

from __future__ import annotations

import numpy as np

from plmarl_sitl.mission import Mission
from plmarl_sitl.sitl.links import u2u_links
from plmarl_sitl.sitl.live_map import MapUav, MapView


class MapSource:
    def __init__(self, mission: Mission, seed: int) -> None:
        self.mission, self.seed = mission, seed
        self._restart()
        self._cached: tuple[float, MapView] | None = None

    def _restart(self) -> None:
        import torch

        from plmarl_sitl.model.users import init_users

        self.gen = torch.Generator().manual_seed(self.seed)
        self.users = init_users(self.mission, 1, self.gen, torch.float32)
        self.k = 0
        self.clusters = tuple(map(tuple, np.unique(self.users.home[0].transpose(0, 1).numpy(), axis=0).tolist()))

    def users_at(self, t: int) -> np.ndarray:
        """(U, 2) (north, east) of the users at mission second t (t < 0: as at t = 0)."""
        from plmarl_sitl.model.users import step_users

        t = max(0, t)
        if t < self.k:
            self._restart()
        while self.k < t:
            self.users = step_users(self.users, self.mission, self.mission.timing.dt_s, self.gen)
            self.k += 1
        return self.users.xy[0].numpy()

    def view(self, t: float | None, uav_rows: list[dict]) -> MapView:
        """The map of mission second t from the world's UAV rows {"id", "alive", "pos"}.
        Computed once per second: the live view redraws 4 times as often."""
        key = -1.0 if t is None else float(t)
        if self._cached is not None and self._cached[0] == key:
            return self._cached[1]
        rows = [{"id": u["id"], "alive": u.get("alive", True), "pos_ned": u.get("pos")} for u in uav_rows]
        both, _ = u2u_links(rows, self.mission)
        uavs = tuple(MapUav(r["id"], r["pos_ned"][0], r["pos_ned"][1], r["alive"]) for r in rows if r["pos_ned"] is not None)
        view = MapView(self.mission.area.north_m, self.mission.area.east_m, uavs,
                       tuple(map(tuple, self.users_at(int(key)).tolist())), self.clusters, tuple(both))
        self._cached = (key, view)
        return view
