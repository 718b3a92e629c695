"""Safety shaping of the commanded acceleration: the twin's altitude band, enforced ahead.

The twin (and the policy it trained) lives in [min_alt, max_alt]: its dynamics stop the
vehicle at the band edges. A real autopilot has no such wall, so the agent brakes before
an edge (with 0.9 A_max) and holds it; a vehicle outside the band (after take-off, or
pushed out) is steered back. Pure function of the state: unit-tested, no I/O.

While braking vertically the horizontal command is dropped: at V_max the point-mass
speed limiter (like a real autopilot's) ignores any command that would raise the speed,
so a brake mixed with a horizontal push could be ignored altogether.
"""

from __future__ import annotations

import math

KP = 0.5  # 1/s^2: return-to-band gain outside the band
KD = 1.2  # 1/s


def band_guard(
    accel: tuple[float, float, float],
    alt_m: float,
    v_up: float,
    alt_min: float,
    alt_max: float,
    a_max: float,
    lead_s: float = 0.15,
) -> tuple[float, float, float]:
    """NED accel (north, east, down) -> the same with the vertical part kept in the band."""
    an, ae, ad = accel
    a_up = -ad
    brake = 0.9 * a_max
    braking = False
    if alt_m < alt_min:
        a_up = max(a_up, min(brake, KP * (alt_min - alt_m) - KD * v_up))
        braking = v_up < 0
    elif alt_m > alt_max:
        a_up = min(a_up, max(-brake, KP * (alt_max - alt_m) - KD * v_up))
        braking = v_up > 0
    elif v_up < 0 and alt_m - alt_min <= v_up * v_up / (2 * brake) - v_up * lead_s:
        a_up, braking = brake, True
    elif v_up > 0 and alt_max - alt_m <= v_up * v_up / (2 * brake) + v_up * lead_s:
        a_up, braking = -brake, True
    if braking:
        return 0.0, 0.0, -a_up
    # Keep the norm within A_max with the vertical part first (the autopilot would clip
    # the norm uniformly and weaken a band correction).
    h = math.hypot(an, ae)
    left = math.sqrt(max(a_max * a_max - a_up * a_up, 0.0))
    if h > left:
        scale = left / h if h > 0 else 0.0
        an, ae = an * scale, ae * scale
    return an, ae, -a_up
