"""`plmarl bench infer`: per-agent decision latency of the exported policies.

One decision of one deployed agent with M = N - 1 neighbours: one belief-tracker step
(predictor.pt over the M neighbours, Algorithm 1) followed by one policy.pt call
(policy input, attention fusion, actor), both TorchScript (the fused deployment form of
plmarl_sitl/learning/nn/fused.py, as exported), torch on ONE thread, no
autograd (inference_mode). Each policy file is called as a deployed agent calls it: one
`PolicyInputs` per decision through `contract.PolicyCall`, which passes the file the inputs
of its version (docs/POLICY_IO.md): version 1 without the demand map, version 2 with it,
and a policy that takes the team plan with its plan point too. Methods and swarm sizes are timed
interleaved, call by call, in the same run, so machine load hits them equally (a ratio N = 100 / N = 4
does not move with the load between them); report the median and the 99th percentile
of the wall time, and the median of the thread's CPU time (on a loaded shared machine the
wall time of a 15 ms plan is mostly waiting for a core).

The team plan (model/service.py, what `deploy/agent/plan.py::AgentPlan` runs beside the
policy) is timed as two extra rows, interleaved the same way, when any timed policy takes it:

* `team plan / decision`: `AgentPlan.target` at a decision whose map the plan already
  follows, as the agent calls it: at second k (k advancing by tau, so the plan-aware
  prediction flies the whole team tau seconds) with its N_i (the failure check);
* `team plan / new map`: `AgentPlan.target` at the decision with a new map (that and the
  re-placement of N service points and, when it serves more users, the re-assignment).
  A map arrives every `demand.refresh_s` (30 s, every 10th decision at tau = 3 s), so every
  10th iteration is a new-map decision and the 9 others plain decisions.

The neighbourhood plan (`coordination: local`, model/local_plan.py, what
`deploy/agent/local_plan.py::LocalAgentPlan` runs) is timed the same way in the rows
`local plan / decision` and `local plan / new map` (its plan over the agent's window).

Its inputs are a real twin instant: the paper's area with N UAVs on their launch line and N
clusters of 60 users on a 200 m lattice (as the suite's zero-shot families), the maps of
t = 0 and of the next map instant alternating. The amortised row is ((decisions per map - 1)
x plan per decision + plan per new map) / decisions per map; a row `METHOD + team plan`
(`METHOD + local plan`) adds it to the decision of each method that takes the plan: the
decision's cost including the coordination. `--area`
sets the side of the square area (the plan grid and the neighbours' positions; the clusters
stay on their 200 m lattice, the launch line through the centre): `--n 4,100 --area 3000`
is issue 24's N = 100 over 3 km. The plan is numpy: run the bench with
OPENBLAS_NUM_THREADS=1, as every deployed agent runs (deploy/agent/program.py); a
multi-threaded BLAS on a loaded machine makes a re-placement 10-100x slower. The result
records the setting.

A method is a name looked up as <--policies>/<name>/, or LABEL=DIR for any policy
directory (to time, say, the shipped and an earlier file set in one run; a DIR that does
not exist is an error). Without a card there, freshly initialised modules of the method's
architecture are timed (latency does not depend on the weights) and the row says
`weights: untrained`.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time
from pathlib import Path
from typing import get_args

from plmarl_sitl.cmdline import comma_list, seed_arg
from plmarl_sitl.machine import machine_info
from plmarl_sitl.mission import Placement

DEFAULT_N = "4,8,12,16,20"
WAVE1 = "pl-marl-wave1"  # the map-memorising PL-MARL shipped before issue 12 (version-1 inputs)
DEFAULT_METHODS = f"pl-marl,gru,{WAVE1}=<project>/policies/wave1/pl-marl"  # as --help shows it (default_methods)


def default_methods() -> str:
    """The shipped files and the wave-1 PL-MARL, wherever the command is run from."""
    from plmarl_sitl.config import PROJECT_POLICIES

    return f"pl-marl,gru,{WAVE1}={PROJECT_POLICIES / 'wave1' / 'pl-marl'}"
PLAN_DECISION = "team plan / decision"
PLAN_MAP = "team plan / new map"
PLAN_AMORTISED = "team plan / amortised"  # per decision: plan per decision + plan per map / decisions per map
WITH_PLAN = " + team plan"  # a plan-taking method's decision plus the amortised plan: the cost including the coordination
# The same three rows and the sum for the neighbourhood plan (coordination: local, model/local_plan.py)
LOCAL_DECISION = "local plan / decision"
LOCAL_MAP = "local plan / new map"
LOCAL_AMORTISED = "local plan / amortised"
WITH_LOCAL = " + local plan"
COORDINATIONS = {"team": (PLAN_DECISION, PLAN_MAP, PLAN_AMORTISED, WITH_PLAN),
                 "local": (LOCAL_DECISION, LOCAL_MAP, LOCAL_AMORTISED, WITH_LOCAL)}
PAPER = Path(__file__).resolve().parents[2] / "missions" / "paper_urban.yaml"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--n", default=DEFAULT_N, type=comma_list(int, "swarm size", positive=True),
                   help=f"swarm sizes N (M = N - 1 neighbours) (default: {DEFAULT_N})")
    p.add_argument("--methods", default=None,
                   help=f"methods to time side by side: NAME (<--policies>/NAME; without a card.yaml there, untrained modules "
                        f"of that method) or LABEL=DIR (DIR must exist) (default: {DEFAULT_METHODS}: the shipped files "
                        "and the wave-1 PL-MARL, the baseline the decision's cost is judged against)")
    p.add_argument("--policies", default=None,
                   help="directory with <method>/predictor.pt, policy.pt (default: the project's policies/, from any directory)")
    p.add_argument("--calls", type=int, default=3000, help="timed decisions per method and N (default: 3000)")
    p.add_argument("--seed", type=seed_arg, default=0, help="seed of the random inputs (default: 0)")
    p.add_argument("--area", type=area_side, default=None, metavar="M",
                   help="side of the square area of the team plan's map and of the neighbours' positions, metres "
                        "(default: the paper mission's, 1000); e.g. --n 4,100 --area 3000 for the cost of N = 100 over 3 km")
    p.add_argument("--placement", choices=get_args(Placement), default=None,
                   help="how the team plan places its points (the mission key `placement`; default: the mission default, "
                        "`search` up to 20 points, the greedy above); e.g. --placement greedy to time the same placement "
                        "at every N")


def parse_methods(text: str, policies: Path) -> dict[str, tuple[str, Path]]:
    """'pl-marl,old=runs/x/pl-marl' -> {label: (method name for untrained modules, directory)}.

    A directory given as LABEL=DIR must exist (UserError): a mistyped path would otherwise
    time untrained modules under the label the user meant for a file set. A bare NAME
    without <policies>/NAME/card.yaml is timed untrained, as the help says."""
    from plmarl_sitl.errors import UserError

    out = {}
    for part in (p.strip() for p in text.split(",") if p.strip()):
        label, eq, where = part.partition("=")
        if not eq:
            out[label] = (label, policies / label)
            continue
        if not label.strip() or not where.strip():
            raise UserError(f"--methods {part!r}: give LABEL=DIR")
        if not Path(where).is_dir():
            raise UserError(f"--methods {part}: no such directory {where}")
        out[label] = (label, Path(where))
    return out


def _modules(method: str, d: Path):
    from plmarl_sitl.learning.nn.fused import fuse_policy, fuse_tracker
    from plmarl_sitl.learning.nn.io import POLICY_ATTRS, TRACKER_ATTRS, freeze, load_policy
    from plmarl_sitl.learning.train.mappo import METHOD_PREDICTOR

    if (d / "card.yaml").is_file():
        lp = load_policy(d)
        return lp.tracker, lp.policy, "trained"
    import torch

    from plmarl_sitl.learning.nn import Actor, BeliefTracker, DeployedPolicy, make_predictor

    torch.manual_seed(0)
    tracker = BeliefTracker(make_predictor(METHOD_PREDICTOR.get(method, "mlp")), 10, 1.0)
    policy = DeployedPolicy(Actor(reads_map=False), 150.0, 20.0, 5.0, 350.0, 100.0, 60.0)  # what `plmarl train` makes
    return freeze(fuse_tracker(tracker), TRACKER_ATTRS), freeze(fuse_policy(policy), POLICY_ATTRS), "untrained"  # as exported


def area_side(text: str) -> float:
    """--area: a finite side of at least 100 m (a mission's smallest area)."""
    try:
        v = float(text)
    except ValueError:
        v = float("nan")
    if not 100.0 <= v < float("inf"):
        raise argparse.ArgumentTypeError(f"{text!r} is not a side of at least 100 m")
    return v


def lattice_mission(n: int, area_m: float | None = None, placement: str | None = None):  # noqa: ANN201 - Mission
    """The paper's area (or a square of side area_m, launch line through its centre) with N
    UAVs and N clusters of 60 users on a 200 m lattice (missions/suite/n20.yaml), its plan
    placed by `placement` (None: the mission default)."""
    from plmarl_sitl.mission import Area, load_mission

    m = load_mission(PAPER)
    users = dataclasses.replace(m.users, count=n * m.users.cluster_size, layout="lattice", cluster_centers=(),
                                cluster_spacing_m=200.0)
    launch = dataclasses.replace(m.launch, spacing_m=25.0)
    if area_m is not None:
        m = dataclasses.replace(m, area=Area(area_m, area_m))
        launch = dataclasses.replace(launch, north_m=area_m / 2, east_m=area_m / 2)
    m = dataclasses.replace(m, n_uavs=n, users=users, launch=launch)
    return m if placement is None else m.with_placement(placement)


@dataclasses.dataclass
class PlanInputs:
    """Agent 0's view at the first decision, and the two maps it alternates between (wire form: nonzero cells)."""

    mission: object
    ego: object
    held: object
    t_rx: object
    maps: list
    decisions_per_map: int


def plan_inputs(n: int, seed: int, area_m: float | None = None, placement: str | None = None) -> PlanInputs:
    import torch

    from plmarl_sitl.model.demand import map_period
    from plmarl_sitl.twin.env import CoverageEnv

    m = lattice_mission(n, area_m, placement)
    env = CoverageEnv(m, 1, seed)
    obs = env.reset()
    first = (obs.ego[0, 0].clone(), obs.nbr_state[0, 0].clone(), obs.nbr_t_rx[0, 0].clone())
    period = map_period(m.demand.refresh_s, m.timing.decision_every_s)
    maps = [obs.demand[0].clone()]
    while obs.t < period:
        obs, _, _ = env.step(torch.zeros(1, n, 3))
    maps.append(obs.demand[0].clone())
    wire = [c[c[:, 2] > 0] for c in maps]
    return PlanInputs(m, *first, wire, period // int(m.timing.decision_every_s))


class _SizeBench:
    """One swarm size's decision, set up as an agent of that size holds it; `step` times one
    decision of every method (and the plan's decision or new map). `run` steps the sizes in
    turn, call by call, so a change of the machine's load falls on every size alike."""

    def __init__(self, mods: dict, n: int, gen, seed: int, area_m: float | None = None,  # noqa: ANN001
                 placement: str | None = None) -> None:
        import torch

        from plmarl_sitl.deploy.agent.coordination import agent_plan
        from plmarl_sitl.deploy.agent.plan import AgentPlan
        from plmarl_sitl.learning.nn.contract import PolicyCall, PolicyInputs
        from plmarl_sitl.model.coverage import SENSING_FEATURES

        self.mods, self.n = mods, n
        self.inputs = PolicyInputs  # imported once, not inside the timed decision
        m_nbrs = n - 1
        side = 1000.0 if area_m is None else area_m
        self.held = torch.cat([torch.rand(m_nbrs, 3, generator=gen) * torch.tensor([side, side, -100.0]),
                               torch.randn(m_nbrs, 3, generator=gen)], -1)
        self.t_rx = torch.zeros(m_nbrs)
        self.ego = torch.tensor([side / 2, side / 2, -100.0, 1.0, 0.0, 0.0])
        self.mask = torch.ones(m_nbrs, dtype=torch.bool)
        self.sense = torch.rand(SENSING_FEATURES, generator=gen)
        self.fail = torch.tensor(False)
        self.policy_calls = {m: PolicyCall(p) for m, (_, p, _) in mods.items()}  # once: attribute reads are slow
        with_plan = any(c.form.takes_plan for c in self.policy_calls.values())
        self.pi = pi = plan_inputs(n, seed, area_m, placement) if with_plan else None
        self.demand = pi.maps[0] if pi is not None else torch.cat(
            [torch.rand(16, 2, generator=gen) * 1000.0, 1.0 + 10.0 * torch.rand(16, 1, generator=gen)], -1)
        self.plans, self.motions, self.target = {}, {}, None
        if pi is not None:
            # What an agent pays at each decision (deploy/agent/decision.py): `target` at second k,
            # k advancing by tau (the team plan's plan-aware prediction flies the team that far),
            # with its N_i (the failure check); a new map every decisions_per_map decisions.
            self.full = torch.ones(n, dtype=torch.bool)
            self.full[0] = False
            self.tau = int(pi.mission.timing.decision_every_s)
            for coord in COORDINATIONS:
                plan = agent_plan(pi.mission.with_coordination(coord), 0)
                self.target = plan.target(0, pi.ego, pi.held, pi.t_rx, (0.0, pi.maps[0]), self.full)  # the plan starts
                self.plans[coord] = (plan, [0, 0])  # (plan, [second k, map number])
                self.motions[coord] = plan.plans.motion if isinstance(plan, AgentPlan) else None  # the team plan's prediction
        self.times: dict[str, list[int]] = {m: [] for m in mods}
        self.cpu: dict[str, list[int]] = {m: [] for m in mods}  # the thread's CPU time: what a loaded machine does not inflate
        if pi is not None:
            for rows_of in COORDINATIONS.values():
                for label in rows_of[:2]:
                    self.times[label], self.cpu[label] = [], []
        self.state = {}
        with torch.inference_mode():
            for m, (tracker, _, _) in mods.items():
                buf, seen = tracker.init_state(self.held)
                _, _, buf, seen = tracker(0.0, self.held, self.t_rx, buf, seen)  # first reception
                self.state[m] = (buf, seen)

    def plan_decision(self, coord: str) -> None:
        plan, kt = self.plans[coord]
        kt[0] += self.tau
        pi = self.pi
        plan.target(kt[0], pi.ego, pi.held, pi.t_rx, (float(kt[1]), pi.maps[kt[1] % 2]), self.full)
        motion = self.motions[coord]
        if motion is not None:
            # The team plan's prediction flies the seconds `advance` booked when a state is read
            # (model/plan_motion.py): in the agent, the failure check reads it at each instant;
            # here no neighbour is silent and nothing would: read it, so each decision pays for
            # its own seconds, as before session 16, not one decision in a map period for all.
            motion.at_array(kt[0])

    def plan_map(self, coord: str) -> None:
        self.plans[coord][1][1] += 1
        self.plan_decision(coord)

    def decide(self, m: str) -> None:
        tracker = self.mods[m][0]
        buf, seen = self.state[m]
        belief, _, _, _ = tracker(7.0, self.held, self.t_rx, buf, seen)  # P-AoI 7: the predictor runs
        self.policy_calls[m](self.inputs(self.ego, belief, self.mask, self.sense, self.fail, self.demand,
                                          self.target))  # each file takes its version's inputs

    def timed(self, label: str, fn) -> None:  # noqa: ANN001
        t0, c0 = time.perf_counter_ns(), time.thread_time_ns()
        fn()
        self.times[label].append(time.perf_counter_ns() - t0)
        self.cpu[label].append(time.thread_time_ns() - c0)

    def warm_up(self, i: int) -> None:  # TorchScript's profiling runs
        for m in self.mods:
            self.decide(m)
        if self.pi is not None:
            for coord in COORDINATIONS:
                self.plan_decision(coord)
                if i % 30 == 0:
                    self.plan_map(coord)

    def step(self, i: int) -> None:
        for m in self.mods:
            self.timed(m, lambda m=m: self.decide(m))
        if self.pi is not None:
            for coord, (dec, new_map, _, _) in COORDINATIONS.items():
                if i % self.pi.decisions_per_map == 0:
                    self.timed(new_map, lambda c=coord: self.plan_map(c))
                else:
                    self.timed(dec, lambda c=coord: self.plan_decision(c))

    def rows(self) -> list[dict]:
        import numpy as np

        n, rows = self.n, []
        for m, ts in self.times.items():
            a = np.asarray(ts) / 1e3
            rows.append({"method": m, "n": n, "median_us": float(np.median(a)), "p99_us": float(np.percentile(a, 99)),
                         "cpu_median_us": float(np.median(np.asarray(self.cpu[m]) / 1e3)), "calls": len(ts)})
        if self.pi is not None:
            med = {r["method"]: r["median_us"] for r in rows}
            med_cpu = {r["method"]: r["cpu_median_us"] for r in rows}
            per = self.pi.decisions_per_map
            for dec, new_map, amort, with_ in COORDINATIONS.values():
                # per decision: (per - 1) decisions on the map the plan follows and one with a new map
                amortised, amortised_cpu = (((per - 1) * x[dec] + x[new_map]) / per for x in (med, med_cpu))
                rows.append({"method": amort, "n": n, "decisions_per_map": per,
                             "median_us": amortised, "p99_us": None, "cpu_median_us": amortised_cpu, "calls": 0})
                for m in self.mods:  # the decision including the coordination, for the methods that take the plan
                    if self.policy_calls[m].form.takes_plan:
                        rows.append({"method": m + with_, "n": n, "median_us": med[m] + amortised, "p99_us": None,
                                     "cpu_median_us": med_cpu[m] + amortised_cpu, "calls": 0})
        return rows


def time_sizes(mods: dict, ns: list[int], calls: int, gen, seed: int, area_m: float | None = None,  # noqa: ANN001
               placement: str | None = None) -> list[dict]:
    """Every size set up first (in order, so the generator's draws are each size's own), warmed
    up, then timed call by call in turn."""
    import torch

    benches = [_SizeBench(mods, n, gen, seed, area_m, placement) for n in ns]
    with torch.inference_mode():
        for i in range(300):
            for b in benches:
                b.warm_up(i)
        for i in range(calls):
            for b in benches:
                b.step(i)
    return [r for b in benches for r in b.rows()]


def run(args: argparse.Namespace) -> dict:
    import torch

    torch.set_num_threads(1)
    load_start = [float(x) for x in os.getloadavg()]
    from plmarl_sitl.config import PROJECT_POLICIES

    policies = Path(args.policies) if args.policies else PROJECT_POLICIES
    methods = parse_methods(args.methods or default_methods(), policies)
    mods = {label: _modules(name, d) for label, (name, d) in methods.items()}
    gen = torch.Generator().manual_seed(args.seed)
    placement = getattr(args, "placement", None)
    rows = time_sizes(mods, list(args.n), args.calls, gen, args.seed, getattr(args, "area", None), placement)
    weights = {m: mods[m][2] for m in mods}
    return {"rows": rows, "weights": weights, "dirs": {m: str(d) for m, (_, d) in methods.items()},
            "machine": machine_info(), "torch_threads": 1, "calls": args.calls, "area_m": getattr(args, "area", None) or 1000.0,
            "placement": placement or "the mission default",
            "openblas_threads": os.environ.get("OPENBLAS_NUM_THREADS", "default"),
            "load_avg_start": load_start, "load_avg": [float(x) for x in os.getloadavg()]}


def print_table(res: dict) -> None:
    from rich.console import Console
    from rich.table import Table

    t = Table(title=f"per-agent decision latency (tracker + policy, TorchScript, 1 thread), {res['machine']}")
    for c in ("method", "N", "median (us)", "p99 (us)", "CPU median (us)", "weights"):
        t.add_column(c, justify="right" if c != "method" else "left")
    for r in res["rows"]:
        t.add_row(r["method"], str(r["n"]), f"{r['median_us']:.1f}", "-" if r["p99_us"] is None else f"{r['p99_us']:.1f}",
                  f"{r['cpu_median_us']:.1f}", res["weights"].get(r["method"], ""))
    Console().print(t)
    Console().print(f"load average {res['load_avg_start']} at the start, {res['load_avg']} at the end, OPENBLAS_NUM_THREADS={res['openblas_threads']}")
    by = {(r["method"], r["n"]): r["median_us"] for r in res["rows"]}
    ns = sorted({r["n"] for r in res["rows"]})
    by_cpu = {(r["method"], r["n"]): r["cpu_median_us"] for r in res["rows"]}
    for _, new_map, _, with_ in COORDINATIONS.values():
        for m in sorted({r["method"] for r in res["rows"] if r["method"].endswith(with_)}):
            if (m, ns[0]) in by and (m, ns[-1]) in by and len(ns) > 1:
                Console().print(f"{m} (the decision including the coordination) N={ns[-1]} / N={ns[0]}: "
                                f"{by[(m, ns[-1])] / by[(m, ns[0])]:.2f} (CPU {by_cpu[(m, ns[-1])] / by_cpu[(m, ns[0])]:.2f}); "
                                f"a new map at N={ns[-1]}: {by[(new_map, ns[-1])] / 1e3:.1f} ms "
                                f"(CPU {by_cpu[(new_map, ns[-1])] / 1e3:.1f} ms), area {res['area_m']:g} m, "
                                f"placement: {res.get('placement', 'the mission default')}")
    if ("pl-marl", ns[0]) in by and ("pl-marl", ns[-1]) in by:
        msg = f"pl-marl N={ns[-1]} / N={ns[0]}: {by[('pl-marl', ns[-1])] / by[('pl-marl', ns[0])]:.2f}"
        if ("gru", ns[-1]) in by:
            msg += f"; gru / pl-marl at N={ns[-1]}: {by[('gru', ns[-1])] / by[('pl-marl', ns[-1])]:.2f}x"
        if (WAVE1, ns[-1]) in by:
            msg += f"; pl-marl / {WAVE1} at N={ns[-1]}: {by[('pl-marl', ns[-1])] / by[(WAVE1, ns[-1])]:.2f}x"
        Console().print(msg)
