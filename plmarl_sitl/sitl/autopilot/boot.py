"""Start-up of the emulated autopilots: instant (fast SITL) or on the real autopilot's timeline.

A real ArduCopter has no home until its EKF sets an origin (~19 s after its link comes up)
and no local position until the EKF uses GPS (~40 s); it refuses to arm in GUIDED before
that. `--boot real` replays that timeline (`Personality.boot_timeline`) in sim time, so a
client that works against the emulator also survives the real start-up; `--boot instant`
(the default) has everything ready at sim time 0.
"""

from __future__ import annotations

from plmarl_sitl.deploy.mavlink.personality import BootTimeline, Personality
from plmarl_sitl.errors import UserError

BOOT_MODES = ("instant", "real")


def boot_timeline(personality: Personality, boot: str) -> BootTimeline | None:
    """The timeline a host of `personality` boots on (None: instant); bad names are UserErrors."""
    if boot not in BOOT_MODES:
        raise UserError(f"--boot must be one of {', '.join(BOOT_MODES)}, got {boot!r}")
    if boot == "instant":
        return None
    if personality.boot_timeline is None:
        raise UserError(f"--boot real: no measured start-up timeline for the {personality.name} personality "
                        "(use --boot instant)")
    return personality.boot_timeline


def check_boot(personality_name: str, boot: str) -> None:
    """Fail with one UserError line, before anything starts, on a bad personality or boot."""
    from plmarl_sitl.deploy.mavlink.personality import personality

    boot_timeline(personality(personality_name), boot)


class Boot:
    """Which start-up stages a host's vehicles (all booted at sim time 0) have reached."""

    def __init__(self, timeline: BootTimeline | None) -> None:
        self.timeline = timeline
        self._next_text = 0
        self._origin_announced = timeline is None

    def ready(self, now: float) -> bool:
        return self.timeline is None or now >= self.timeline.ready_s

    def attitude(self, now: float) -> bool:
        return self.timeline is None or now >= self.timeline.attitude_s

    def origin(self, now: float) -> bool:
        return self.timeline is None or now >= self.timeline.origin_s

    def position(self, now: float) -> bool:
        return self.timeline is None or now >= self.timeline.position_s

    def due_texts(self, now: float) -> list[str]:
        """STATUSTEXTs whose instant has come since the last call."""
        tl = self.timeline
        if tl is None or self._next_text >= len(tl.texts):
            return []
        out = []
        while self._next_text < len(tl.texts) and tl.texts[self._next_text][0] <= now:
            out.append(tl.texts[self._next_text][1])
            self._next_text += 1
        return out

    def origin_just_set(self, now: float) -> bool:
        """True once, at the first call after the origin is set: the real one then sends
        HOME_POSITION and GPS_GLOBAL_ORIGIN unasked."""
        if self._origin_announced or not self.origin(now):
            return False
        self._origin_announced = True
        return True
