"""One agent's decision (`Decision.second` at a decision second, N = 20) timed in isolation,
back to back and with a sleep before each call: how much of the loop's cost is a cold
cache after the process slept (docs/RESULTS.md, issue 5, "Loop p99"). Also the mean CPU
of every mission second, decided or not: since session 16 the tracker steps of the seconds
between decisions run at the decision (`Decision.track`), so the decision's own figure
includes them and the per-second mean is the one to compare across that change.

    python -m plmarl_sitl.bench.decision_cold [--sleeps-ms 0,10,100] [--calls 300]
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import time

import torch

from plmarl_sitl.cmdline import comma_list
from plmarl_sitl.config import PAPER_MISSION, PROJECT_POLICIES
from plmarl_sitl.deploy.agent.clock import MissionClock
from plmarl_sitl.deploy.agent.decision import Decision
from plmarl_sitl.deploy.agent.neighbours import NeighbourTable
from plmarl_sitl.deploy.agent.stats import LoopStats, Trace
from plmarl_sitl.deploy.mqtt.schema import INSTANT_WAIT_WALL_S, Topics
from plmarl_sitl.learning.nn.io import load_policy
from plmarl_sitl.mission import load_mission


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sleeps-ms", type=comma_list(float, "sleep"), default="0,10,100")
    p.add_argument("--calls", type=int, default=300)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args()
    torch.set_num_threads(1)
    torch.manual_seed(args.seed)
    mission = dataclasses.replace(load_mission(PAPER_MISSION), n_uavs=20)
    # Agent 0's decision with what it reads: the mission clock (the agent's default waits),
    # started at boot time 0, and the neighbour table; no trace; the users are given below.
    clock = MissionClock(mission.signalling.tup_s, int(mission.timing.decision_every_s), 0.1, INSTANT_WAIT_WALL_S)
    table = NeighbourTable(20, 0, mission.signalling.drop_after_missed)
    decision = Decision(mission, 0, load_policy(PROJECT_POLICIES / "pl-marl", mission), clock, table, LoopStats(), Trace(None), Topics())
    decision.warm_up()
    decision.sense_history.append((0.0, torch.rand(40, 2) * 100 + 450))
    decision.ego = torch.tensor([500.0, 500.0, -80.0, 1.0, 0.0, 0.0])
    clock.set_t0(0.0)
    k = 0
    print(f"seed {args.seed}; N = 20, decision seconds only")
    for sleep_ms in args.sleeps_ms:
        wall, cpu, every = [], [], []
        while len(wall) < args.calls:
            if k % 15 == 0:  # every neighbour signals at each instant
                for j in range(1, 20):
                    table.on_state(j, float(k), tuple((torch.randn(6) * 50 + torch.tensor([500, 500, -80, 0, 0, 0.0])).tolist()))
            time.sleep(sleep_ms / 1e3)
            t, c = time.perf_counter(), time.thread_time()
            decided = decision.second(k)
            if k >= 30:
                every.append((time.thread_time() - c) * 1e3)
            if decided and k >= 30:
                wall.append((time.perf_counter() - t) * 1e3)
                cpu.append((time.thread_time() - c) * 1e3)
            k += 1
        wall.sort()
        cpu.sort()
        print(f"sleep {sleep_ms:g} ms before each second: decision wall p50 {statistics.median(wall):.3f} ms "
              f"p99 {wall[int(0.99 * len(wall))]:.3f} ms, CPU p50 {statistics.median(cpu):.3f} ms; "
              f"every second: CPU mean {statistics.mean(every):.3f} ms")


if __name__ == "__main__":
    main()
