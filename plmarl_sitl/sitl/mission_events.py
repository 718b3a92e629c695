"""One dispatcher for a SITL run's mission events: each part registers what it does.

The mission's one schedule (`model.events.EventSchedule`, the twin's too) says what changes
at each mission second. In a SITL run two parts act on it: the world (the vehicle of a
failed node, the link emulator's cuts, GNSS noise and autopilot faults, the T_up on the
`ctl` topic) and the launcher (a failed node's agent process, the broker gate, the record
in events.jsonl). Each registers a handler per event type on the world's dispatcher, and
the world dispatches once per mission second, so no part switches on type strings.

Order: for each change (in the schedule's order), the handlers of its type in the order
they were registered (the world's first: it registers at construction), then every
handler of all changes; then the UAVs an autopilot fault takes out of the mission.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Callable

from plmarl_sitl.mission import Event
from plmarl_sitl.model.events import Change, EventSchedule

OnChange = Callable[[Change], None]
OnFaultFailure = Callable[[int, Event, int], None]  # (uav, the fault, mission second)


class EventDispatcher:
    def __init__(self, schedule: EventSchedule | None) -> None:
        self.schedule = schedule  # None: a run without events
        self._by_type: defaultdict[str, list[OnChange]] = defaultdict(list)
        self._every: list[OnChange] = []
        self._fault_failures: list[OnFaultFailure] = []

    def on(self, kind: str, handler: OnChange) -> None:
        """`handler` gets every change (start, and end if it lasts) of events of this type."""
        self._by_type[kind].append(handler)

    def on_every(self, handler: OnChange) -> None:
        """`handler` gets every change, after the handlers of its type."""
        self._every.append(handler)

    def on_fault_failure(self, handler: OnFaultFailure) -> None:
        """`handler` gets each UAV an autopilot fault takes out of the mission, at that second."""
        self._fault_failures.append(handler)

    def dispatch(self, second: int) -> None:
        """Everything the schedule changes at this mission second."""
        if self.schedule is None:
            return
        for change in self.schedule.changes_at(second):
            for handler in self._by_type.get(change.event.type, ()):
                handler(change)
            for handler in self._every:
                handler(change)
        for uav, ev in self.schedule.fault_failures_at(second):
            for fault_handler in self._fault_failures:
                fault_handler(uav, ev, second)
