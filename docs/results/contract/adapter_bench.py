"""Issue 24 (docs/RESULTS.md, "One policy contract"): the adapter's cost in ONE process, the
file's positional call against `lp.call(PolicyInputs(...))`, interleaved call by call, 1 thread.

    PYTHONPATH=<checkout> python adapter_bench.py [CALLS]
"""

from __future__ import annotations

import statistics
import sys
import time

import torch

from plmarl_sitl.config import PROJECT_POLICIES
from plmarl_sitl.learning.nn.contract import PolicyInputs
from plmarl_sitl.learning.nn.io import load_policy


def main(calls: int) -> None:
    torch.set_num_threads(1)
    gen = torch.Generator().manual_seed(0)
    for name in ["pl-marl", "wave1/pl-marl"]:
        lp = load_policy(PROJECT_POLICIES / name)
        call, policy, arity = lp.call, lp.policy, lp.call.arity
        for n in (4, 20):
            m = n - 1
            ego = torch.tensor([500.0, 500.0, -100.0, 1.0, 0.0, 0.0])
            bel = torch.cat([torch.rand(m, 3, generator=gen) * torch.tensor([1000.0, 1000.0, -100.0]),
                             torch.randn(m, 3, generator=gen)], -1)
            mask, sense, fail = torch.ones(m, dtype=torch.bool), torch.rand(4, generator=gen), torch.tensor(False)
            demand = torch.cat([torch.rand(16, 2, generator=gen) * 1000.0, 1.0 + 10.0 * torch.rand(16, 1, generator=gen)], -1)
            target = torch.tensor([400.0, 600.0])
            args = (ego, bel, mask, sense, fail, demand, target)[:arity]  # the file's positional inputs
            old, new = [], []
            with torch.inference_mode():
                for _ in range(300):  # warm-up (TorchScript's profiling runs)
                    policy(*args)
                    call(PolicyInputs(ego, bel, mask, sense, fail, demand, target))
                for _ in range(calls):
                    t0 = time.perf_counter_ns()
                    policy(*args)
                    t1 = time.perf_counter_ns()
                    call(PolicyInputs(ego, bel, mask, sense, fail, demand, target))
                    t2 = time.perf_counter_ns()
                    old.append(t1 - t0)
                    new.append(t2 - t1)
            a, b = statistics.median(old) / 1e3, statistics.median(new) / 1e3
            print(f"{name:14s} N={n:2d}  positional {a:6.1f} us   PolicyCall(PolicyInputs) {b:6.1f} us   diff {b - a:+.2f} us")


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 3000)
