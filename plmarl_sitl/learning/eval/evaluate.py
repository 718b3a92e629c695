"""Deterministic evaluation sweeps in the twin: methods x T_up, paired episodes.

Every method sees the same episodes: batch k of a sweep point uses twin seed `seed + k`,
and no controller draws from the twin's generator, so users start and move identically.
That makes "fraction of the best reference on the same episodes" (learning/eval/references.py)
and paired comparisons exact.

Coverage of an episode = mean C(t) over the steady-state window t in (from_s, T]
(default: after the first 50 s, which the swarm needs to fly out from the launch line;
the paper's Fig. 3b reports steady-state coverage). The full-episode mean is reported
beside it. lambda_2 is averaged over the same window.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from plmarl_sitl.errors import UserError
from plmarl_sitl.learning.eval.controllers import LearnedController
from plmarl_sitl.learning.eval.methods import ALL_METHODS, GLOBAL_KNOWLEDGE
from plmarl_sitl.learning.eval.references import best_reference
from plmarl_sitl.learning.eval.stats import compare, mean_ci95
from plmarl_sitl.learning.nn.io import LoadedPolicy, script
from plmarl_sitl.learning.train.predictor import dead_reckoning_tracker
from plmarl_sitl.mission import Mission
from plmarl_sitl.model.repairs import STATION_M
from plmarl_sitl.twin.rollout import MakeController, rollout

LEARNT = ("pl-marl", "gru", "tag-mappo")
# `service-track` and `pl-marl-track`: metres the plan point follows the sensed users (model/sensed_track.py),
# chosen on training-seed probes (docs/RESULTS.md, session 19); a mission's own track_sensed_m > 0 is kept
TRACK_METHOD_M = 30.0
# pl-marl-transit's distance: the product's "on station" (model/repairs.py::STATION_M; session 28: at 50 m the
# plan follower also took over after every new map of walking crowds, whose points move 50-90 m)
TRANSIT_METHOD_M = STATION_M


@dataclass
class MethodRun:
    coverage: np.ndarray  # (E,) steady-state mean C
    coverage_full: np.ndarray  # (E,) whole-episode mean C
    lambda2: np.ndarray  # (E,) steady-state mean lambda_2
    trace: np.ndarray  # (E, T) C(t)


def needed_policies(methods: list[str]) -> set[str]:
    need = {m for m in methods if m in LEARNT}
    if {"dead-reckoning", "pl-marl-learned", "pl-marl-track", "pl-marl-resolve", "pl-marl-transit"} & set(methods):
        need.add("pl-marl")  # dead reckoning = the PL-MARL policy with a constant-velocity tracker; pl-marl-learned its plan
    return need


def controller_factory(method: str, loaded: dict[str, LoadedPolicy]) -> MakeController:
    if method == "greedy":
        from plmarl_sitl.twin.greedy import GreedyController

        return lambda env: GreedyController(env)
    if method == "clairvoyant":
        from plmarl_sitl.twin.clairvoyant import ClairvoyantController

        return lambda env: ClairvoyantController(env)
    if method == "heuristic":
        from plmarl_sitl.twin.heuristic import HeuristicController

        return lambda env: HeuristicController(env.mission)
    if method == "service":
        from plmarl_sitl.learning.eval.controllers import ServiceController

        return lambda env: ServiceController(env.mission)
    if method == "service-local":  # the plan follower on the neighbourhood plan (issue 24, part 2)
        from plmarl_sitl.learning.eval.controllers import ServiceController

        return lambda env: ServiceController(env.mission.with_coordination("local"))
    if method in ("service-greedy", "service-search", "service-learned"):  # the plan follower on a given placement (issue 24.3)
        from plmarl_sitl.learning.eval.controllers import ServiceController

        placement = method.removeprefix("service-")
        return lambda env: ServiceController(env.mission.with_placement(placement))
    if method == "pl-marl-learned":  # PL-MARL on the team plan with the learnt placement
        lp = loaded["pl-marl"]
        return lambda env: LearnedController(lp.tracker, lp.policy, env.mission.with_placement("learned"))
    if method == "service-track":  # the plan follower following its sensed users between maps (issue 24.3)
        from plmarl_sitl.learning.eval.controllers import ServiceController

        return lambda env: ServiceController(tracking(env.mission))
    if method == "pl-marl-track":
        lp = loaded["pl-marl"]
        return lambda env: LearnedController(lp.tracker, lp.policy, tracking(env.mission))
    if method == "service-resolve":  # failure re-plans re-solve the whole plan (the default until session 27)
        from plmarl_sitl.learning.eval.controllers import ServiceController

        return lambda env: ServiceController(env.mission.with_failure_replan("resolve"))
    if method == "pl-marl-resolve":
        lp = loaded["pl-marl"]
        return lambda env: LearnedController(lp.tracker, lp.policy, env.mission.with_failure_replan("resolve"))
    if method == "pl-marl-transit":  # the plan follower's command in transit (model/plan_follower.py)
        lp = loaded["pl-marl"]
        return lambda env: LearnedController(lp.tracker, lp.policy, in_transit(env.mission))
    if method == "service-fixed":  # the plan follower without failure re-plans (before issue 24)
        from plmarl_sitl.learning.eval.controllers import ServiceController

        return lambda env: ServiceController(env.mission, replan=False)
    if method == "dead-reckoning":
        pol = loaded["pl-marl"].policy
        buffer_len = int(loaded["pl-marl"].card["io"]["buffer_len"])
        cv = script(dead_reckoning_tracker(buffer_len))
        # The ablation replaces the predictor wherever PL-MARL uses one: the tracker's beliefs and
        # the positions a failure re-plan assigns from (constant velocity from each agent's held
        # states, instead of the plan-aware prediction every survivor computes alike).
        return lambda env: LearnedController(cv, pol, env.mission, sources="cv")
    if method in LEARNT:
        lp = loaded[method]
        return lambda env: LearnedController(lp.tracker, lp.policy, env.mission)
    raise UserError(f"unknown method {method!r} (choose from {', '.join(ALL_METHODS)})")


def tracking(mission: Mission) -> Mission:
    """The mission with its plan point following the sensed users (its own track_sensed_m, else TRACK_METHOD_M)."""
    return mission if mission.track_sensed_m > 0 else mission.with_track_sensed(TRACK_METHOD_M)


def in_transit(mission: Mission) -> Mission:
    """The mission with a learnt policy's UAV flying the plan follower's command in transit (its own
    transit_plan_m, else TRANSIT_METHOD_M)."""
    return mission if mission.transit_plan_m > 0 else mission.with_transit_plan(TRANSIT_METHOD_M)


def run_method(
    mission: Mission,
    make: MakeController,
    episodes: int,
    seed: int,
    *,
    batch: int = 50,
    from_s: int = 50,
    failure_prob: float = 0.0,
    on_decision: Callable[[int], None] | None = None,
) -> MethodRun:
    runs = rollout(mission, make, episodes, seed, batch=batch, failure_prob=failure_prob, on_decision=on_decision)
    return MethodRun(
        np.concatenate([r.coverage[:, from_s:].mean(-1).numpy() for r in runs]),
        np.concatenate([r.coverage.mean(-1).numpy() for r in runs]),
        np.concatenate([r.lambda2[:, from_s:].mean(-1).numpy() for r in runs]),
        np.concatenate([r.coverage.numpy() for r in runs]),
    )


def evaluate_methods(
    mission: Mission,
    loaded: dict[str, LoadedPolicy],
    methods: list[str],
    tups: list[int],
    episodes: int,
    seed: int,
    *,
    from_s: int = 50,
    failure_prob: float = 0.0,
    batch: int = 50,
    on_decision: Callable[[int], None] | None = None,
) -> dict:
    """-> {"results": [...], "p_values": [...], "extra": {...}} (see `plmarl eval --help`)."""
    runs: dict[tuple[str, int], MethodRun] = {}
    for tup in tups:
        m = mission.with_tup(tup)
        for method in methods:
            if method in GLOBAL_KNOWLEDGE and tup != tups[0]:  # T_up-independent: run once, serve every T_up
                runs[(method, tup)] = runs[(method, tups[0])]
                continue
            runs[(method, tup)] = run_method(
                m, controller_factory(method, loaded), episodes, seed, batch=batch, from_s=from_s,
                failure_prob=failure_prob, on_decision=on_decision,
            )
    results, p_values, extra = [], [], []
    refs = {t: best_reference({m: (runs[(m, t)].coverage, runs[(m, t)].trace) for m in methods}) for t in tups}
    for tup in tups:
        for method in methods:
            r = runs[(method, tup)]
            mean, (lo, hi) = mean_ci95(r.coverage)
            results.append({"method": method, "tup": tup, "coverage_mean": mean, "coverage_ci95": [lo, hi],
                            "lambda2_mean": float(r.lambda2.mean())})
            row = {"method": method, "tup": tup, "coverage_full_mean": float(r.coverage_full.mean()),
                   "coverage_full_ci95": list(mean_ci95(r.coverage_full)[1])}
            best = refs[tup]
            if best is not None:
                fm, (flo, fhi) = mean_ci95(r.coverage / np.maximum(best.coverage, 1e-9))
                row.update({"fraction_of_best_mean": fm, "fraction_of_best_ci95": [flo, fhi],
                            "best_reference": best.label(), "best_reference_coverage_mean": float(best.coverage.mean())})
            extra.append(row)
        if "pl-marl" in methods:
            for other in methods:
                if other == "pl-marl":
                    continue
                c = compare(runs[("pl-marl", tup)].coverage, runs[(other, tup)].coverage)
                p_values.append({"method": "pl-marl", "versus": other, "tup": tup, **c})
    traces = {f"{m}@{t}": r.trace.mean(0).tolist() for (m, t), r in runs.items()}
    return {"results": results, "p_values": p_values,
            "extra": {"rows": extra, "from_s": from_s, "episodes": episodes, "seed": seed,
                      "failure_prob": failure_prob, "mean_traces": traces,
                      "references": {str(t): None if b is None else b.shares() for t, b in refs.items()}}}
