"""The agent's side of lockstep SITL (`plmarl agent --lockstep`): when a telemetry sample
may be answered.

A lockstep world (`sitl.lockstep`) moves vehicle time only once every live agent has
answered the latest LOCAL_POSITION_NED with a setpoint stamped with its time_boot_ms.
Before it lets vehicle time pass a whole boot second B it publishes everything of that
second (sensing, the instant's deliveries, start, T_up changes), then a `tick` for B.
So the agent holds its answer to the first telemetry of second B until it has the tick
for B: everything the second's processing reads is then in, whatever the wall-clock
timing, and nothing is decided on a wall-clock timeout.

The one exception: while the agent's broker connection is down (a broker outage) no tick
can come, and the agent answers at once, as a free-running one would.
"""

from __future__ import annotations

import math

from plmarl_sitl.deploy.agent.clock import EPS


class TickGate:
    def __init__(self) -> None:
        self.tick_s = -math.inf  # the newest boot second the world has ticked
        self.online = False  # the broker connection is up (ticks can arrive)

    def on_tick(self, boot_s: float) -> None:
        self.tick_s = max(self.tick_s, boot_s)

    def holds(self, boot_s: float) -> bool:
        """A telemetry sample at vehicle time `boot_s` must wait for its second's tick."""
        return self.online and self.tick_s < math.floor(boot_s + EPS)
