"""Link emulator: who hears a broadcast, from the shared channel model.

A receiver i hears sender j when both are alive, within R_comm and the U2U SINR is at
least Gamma (`plmarl_sitl.model.graph.link_mask`, the twin's rule), unless the link is
cut by a mission event or the message is lost (independent Bernoulli per receiver).
Latency is applied by the caller (the world process schedules delivery in sim time).
"""

from __future__ import annotations

import random
from collections.abc import Iterable
from dataclasses import dataclass

import torch

from plmarl_sitl.mission import Mission
from plmarl_sitl.model.graph import link_mask


@dataclass
class LinkCounters:
    offered: int = 0  # (sender, receiver) pairs considered
    delivered: int = 0
    out_of_range: int = 0  # distance or SINR
    lost: int = 0  # random loss
    cut: int = 0  # a cut-links event
    malformed: int = 0  # tx payloads that were not valid state messages
    # Signed wire (schema version 2): tx payloads refused before relaying.
    unsigned: int = 0
    wrong_key: int = 0
    forged: int = 0
    misattributed: int = 0  # the sender field disagrees with the tx topic
    replayed: int = 0  # a (session, seq) not newer than the sender's last relayed one
    out_of_window: int = 0  # an instant too old or too new for the world's mission clock
    outage: int = 0  # lockstep: states an emulated broker outage swallowed (sitl.world)

    def as_dict(self) -> dict[str, int]:
        return dict(self.__dict__)


class LinkEmulator:
    def __init__(self, mission: Mission, n: int, *, loss: float = 0.0, seed: int = 0) -> None:
        if not 0.0 <= loss <= 1.0:
            raise ValueError("loss must be in [0, 1]")
        self.mission = mission
        self.n = n
        self.loss = loss
        self.rng = random.Random(seed)
        self.counters = LinkCounters()
        self._cuts: list[tuple[frozenset[tuple[int, int]] | None, float]] = []  # (pairs or all, until sim s)

    def cut(self, pairs: Iterable[tuple[int, int]] | None, until_s: float) -> None:
        """Cut the given undirected pairs (None: every link) until sim time `until_s`."""
        norm = None if pairs is None else frozenset((min(a, b), max(a, b)) for a, b in pairs)
        self._cuts.append((norm, until_s))

    def _is_cut(self, a: int, b: int, now: float) -> bool:
        self._cuts = [(p, u) for p, u in self._cuts if u > now]
        key = (min(a, b), max(a, b))
        return any(p is None or key in p for p, _ in self._cuts)

    def links(self, pos: torch.Tensor, alive: torch.Tensor) -> torch.Tensor:
        """(N, N) bool [i, j]: i hears j now (channel model only)."""
        rx, _ = link_mask(pos, alive, self.mission.channel, self.mission.radii.comm_m)
        return rx

    def receivers(self, sender: int, pos: torch.Tensor, alive: torch.Tensor, now: float) -> list[int]:
        """Who gets `sender`'s broadcast now; pos (N, 3) mission frame, alive (N,) bool."""
        rx = self.links(pos, alive)
        out = []
        for i in range(self.n):
            if i == sender:
                continue
            self.counters.offered += 1
            if not bool(rx[i, sender]):
                self.counters.out_of_range += 1
            elif self._cuts and self._is_cut(i, sender, now):
                self.counters.cut += 1
            elif self.loss > 0 and self.rng.random() < self.loss:
                self.counters.lost += 1
            else:
                self.counters.delivered += 1
                out.append(i)
        return out
