"""Per-vehicle counters of dropped input.

Bad input must never crash a vehicle or go unnoticed: each category is counted, the first
occurrence is logged and announced to the ground station with a STATUSTEXT, and the totals
are logged periodically by the runner (see `AutopilotHost.log_counters`).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

from plmarl_sitl.deploy.mavlink.codec import FAULTS


@dataclass
class InputCounters:
    """How many datagrams/messages a vehicle received and dropped, by reason."""

    datagrams: int = 0
    messages: int = 0
    garbage: int = 0
    truncated: int = 0
    bad_header: int = 0
    bad_crc: int = 0
    unknown_msg: int = 0
    unsigned: int = 0
    bad_signature: int = 0
    bad_value: int = 0

    def add(self, fault: str) -> bool:
        """Count one drop; True if it is the first of its kind (caller then announces it)."""
        if fault not in FAULTS:
            raise ValueError(f"unknown fault category {fault!r}")
        n = getattr(self, fault) + 1
        setattr(self, fault, n)
        return n == 1

    @property
    def dropped(self) -> int:
        return sum(getattr(self, f) for f in FAULTS)

    def as_dict(self) -> dict[str, int]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def drops(self) -> dict[str, int]:
        """Only the drop counts, by reason: what a mission's record keeps (the traffic volume
        includes the start-up, which follows wall time even in lockstep)."""
        return {f: getattr(self, f) for f in FAULTS}

    def summary(self) -> str:
        """Non-zero drop counts as `reason=n` pairs, for a log line."""
        parts = [f"{f}={getattr(self, f)}" for f in FAULTS if getattr(self, f)]
        return " ".join(parts) or "none"
