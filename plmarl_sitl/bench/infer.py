"""`plmarl bench infer`: per-agent decision latency of the exported policies.

One decision of one deployed agent with M = N - 1 neighbours: one belief-tracker step
(predictor.pt over the M neighbours, Algorithm 1) followed by one policy.pt call
(policy input, attention fusion, actor), both TorchScript (the fused deployment form of
plmarl_sitl/learning/nn/deploy.py, as exported), torch on ONE thread, no
autograd (inference_mode). Methods are timed interleaved, call by call, in the same run,
so machine load hits them equally; report the median and the 99th percentile.

The shipped policies/<method>/ files are used when present; otherwise freshly
initialised modules of the same architecture (latency does not depend on the weights)
and the row says `weights: untrained`. The wave-1 PL-MARL files (policies/wave1/pl-marl,
the map-memorising policy shipped before issue 12) are timed in the same run as the row
`pl-marl-wave1`, the baseline the decision's cost is judged against. Each file is called
with the inputs of its version (docs/POLICY_IO.md): five for version 1, the demand map for
version 2, and the team-plan target where it takes one.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from plmarl_sitl.cmdline import comma_list
from plmarl_sitl.errors import UserError
from plmarl_sitl.machine import machine_info

DEFAULT_N = "4,8,12,16,20"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--n", default=DEFAULT_N, type=comma_list(int, "swarm size", positive=True),
                   help=f"swarm sizes N (M = N - 1 neighbours) (default: {DEFAULT_N})")
    p.add_argument("--methods", default="pl-marl,gru", help="methods to time side by side (default: pl-marl,gru)")
    p.add_argument("--policies", default="policies", help="directory with <method>/predictor.pt, policy.pt")
    p.add_argument("--baseline", default="policies/wave1/pl-marl", metavar="DIR",
                   help="policy timed beside them as pl-marl-wave1 ('' for none; default: policies/wave1/pl-marl)")
    p.add_argument("--calls", type=int, default=3000, help="timed decisions per method and N (default: 3000)")
    p.add_argument("--seed", type=int, default=0, help="seed of the random inputs (default: 0)")


BASELINE = "pl-marl-wave1"


def _modules(method: str, d: Path):
    from plmarl_sitl.learning.nn.deploy import fuse_tracker
    from plmarl_sitl.learning.nn.io import POLICY_ATTRS, TRACKER_ATTRS, freeze, load_policy
    from plmarl_sitl.learning.train.mappo import METHOD_PREDICTOR

    if (d / "card.yaml").is_file():
        lp = load_policy(d)
        return lp.tracker, lp.policy, "trained"
    import torch

    from plmarl_sitl.learning.nn import Actor, BeliefTracker, DeployedPolicy, make_predictor

    torch.manual_seed(0)
    tracker = BeliefTracker(make_predictor(METHOD_PREDICTOR[method]), 10, 1.0)
    policy = DeployedPolicy(Actor(), 150.0, 20.0, 5.0, 350.0, 100.0, 60.0)
    return freeze(fuse_tracker(tracker), TRACKER_ATTRS), freeze(policy, POLICY_ATTRS), "untrained"


def _time_n(mods: dict, n: int, calls: int, gen) -> list[dict]:  # noqa: ANN001
    import numpy as np
    import torch

    from plmarl_sitl.learning.nn.io import input_version, takes_plan
    from plmarl_sitl.model.coverage import SENSING_FEATURES

    m_nbrs = n - 1
    held = torch.cat([torch.rand(m_nbrs, 3, generator=gen) * torch.tensor([1000.0, 1000.0, -100.0]),
                      torch.randn(m_nbrs, 3, generator=gen)], -1)
    t_rx = torch.zeros(m_nbrs)
    ego = torch.tensor([500.0, 500.0, -100.0, 1.0, 0.0, 0.0])
    mask = torch.ones(m_nbrs, dtype=torch.bool)
    sense = torch.rand(SENSING_FEATURES, generator=gen)
    fail = torch.tensor(False)
    # A published demand map of 4 clusters over 100 m cells: ~16 nonzero cells on the wire.
    demand = torch.cat([torch.rand(16, 2, generator=gen) * 1000.0, 1.0 + 10.0 * torch.rand(16, 1, generator=gen)], -1)
    target = torch.tensor([520.0, 480.0])  # the agent's team-plan point
    extra = {m: (() if input_version(policy) < 2 else (demand, target) if takes_plan(policy) else (demand,))
             for m, (_, policy, _) in mods.items()}
    state = {}
    times: dict[str, list[int]] = {m: [] for m in mods}
    with torch.inference_mode():
        for m, (tracker, _, _) in mods.items():
            buf, seen = tracker.init_state(held)
            _, _, buf, seen = tracker(0.0, held, t_rx, buf, seen)  # first reception
            state[m] = (buf, seen)

        def decide(m: str) -> None:
            tracker, policy, _ = mods[m]
            buf, seen = state[m]
            belief, _, _, _ = tracker(7.0, held, t_rx, buf, seen)  # P-AoI 7: the predictor runs
            policy(ego, belief, mask, sense, fail, *extra[m])

        for _ in range(300):  # warm-up (TorchScript's profiling runs)
            for m in mods:
                decide(m)
        for _ in range(calls):
            for m in mods:
                t0 = time.perf_counter_ns()
                decide(m)
                times[m].append(time.perf_counter_ns() - t0)
    rows = []
    for m in mods:
        a = np.asarray(times[m]) / 1e3
        rows.append({"method": m, "n": n, "median_us": float(np.median(a)), "p99_us": float(np.percentile(a, 99))})
    return rows


def run(args: argparse.Namespace) -> dict:
    import torch

    torch.set_num_threads(1)
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    mods = {m: _modules(m, Path(args.policies) / m) for m in methods}
    if args.baseline:
        if not (Path(args.baseline) / "card.yaml").is_file():
            raise UserError(f"--baseline {args.baseline}: no card.yaml there")
        mods[BASELINE] = _modules("pl-marl", Path(args.baseline))
    gen = torch.Generator().manual_seed(args.seed)
    rows = []
    for n in args.n:
        rows += _time_n(mods, n, args.calls, gen)
    return {"rows": rows, "weights": {m: mods[m][2] for m in mods}, "baseline": args.baseline or None, "machine": machine_info(), "torch_threads": 1,
            "calls": args.calls}


def print_table(res: dict) -> None:
    from rich.console import Console
    from rich.table import Table

    t = Table(title=f"per-agent decision latency (tracker + policy, TorchScript, 1 thread), {res['machine']}")
    for c in ("method", "N", "median (us)", "p99 (us)", "weights"):
        t.add_column(c, justify="right" if c != "method" else "left")
    for r in res["rows"]:
        t.add_row(r["method"], str(r["n"]), f"{r['median_us']:.1f}", f"{r['p99_us']:.1f}", res["weights"][r["method"]])
    Console().print(t)
    by = {(r["method"], r["n"]): r["median_us"] for r in res["rows"]}
    ns = sorted({r["n"] for r in res["rows"]})
    if ("pl-marl", ns[0]) in by and ("pl-marl", ns[-1]) in by:
        msg = f"pl-marl N={ns[-1]} / N={ns[0]}: {by[('pl-marl', ns[-1])] / by[('pl-marl', ns[0])]:.2f}"
        if ("gru", ns[-1]) in by:
            msg += f"; gru / pl-marl at N={ns[-1]}: {by[('gru', ns[-1])] / by[('pl-marl', ns[-1])]:.2f}x"
        if (BASELINE, ns[-1]) in by:
            msg += f"; pl-marl / {BASELINE} at N={ns[-1]}: {by[('pl-marl', ns[-1])] / by[(BASELINE, ns[-1])]:.2f}x"
        Console().print(msg)
