"""A free-running world's pace against its --speedup: how much mission time it has lost.

The world's clock catches up at most `CATCHUP_TICKS` tick periods of wall time at a tick
(a stall must not make vehicle time jump ahead of the agents); wall time beyond that is
lost for good, and the mission runs slower than --speedup. Without a word, a user learns
it only from the final "achieved" figure; `Pace` says so once, during the mission.
"""

from __future__ import annotations

CATCHUP_TICKS = 5  # tick periods of wall time one tick may catch up at most
BEHIND_NOTICE_S = 2.0  # mission seconds lost before the world says it runs behind


class Pace:
    def __init__(self, speedup: float, notice_s: float = BEHIND_NOTICE_S) -> None:
        self.speedup = speedup
        self.notice_s = notice_s
        self.lost_s = 0.0  # mission seconds lost to the bounded catch-up
        self.said = False

    def lose(self, wall_s: float) -> None:
        """Wall time the clock did not catch up (beyond the bound)."""
        self.lost_s += wall_s * self.speedup

    def notice(self, mission_s: float, wall_s: float) -> str | None:
        """The once-per-run message, when more than `notice_s` mission seconds are lost
        (`mission_s` advanced in `wall_s` since the mission began), else None."""
        if self.said or self.lost_s <= self.notice_s or wall_s <= 0.0:
            return None
        self.said = True
        return (f"running behind --speedup {self.speedup:g} (achieving {mission_s / wall_s:.1f}x); "
                "lower --speedup or use --lockstep")
