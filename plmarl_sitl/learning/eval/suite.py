"""The held-out evaluation suite: named scenario families, seeds no training run uses.

A suite file (missions/suite/suite.yaml) lists families; a family is a list of mission
YAMLs (usually `extends: ../paper_urban.yaml` with one change). Its E episodes are spread
over its missions in turn (episode i runs mission i mod len(missions)); mission variant v
of run `--seed S` seeds its twin batches with `suite_twin_seed(S, v, k)`, all at or above
EVAL_SEED_BASE, a range every training twin refuses (plmarl_sitl/learning/train/seeds.py).
Every method sees the same episodes, so the fraction of the best reference (per episode, the
best of greedy, clairvoyant and service among those run: learning/eval/references.py) is exact.

The rollouts are `evaluate.run_method` (coverage = mean C(t) for t > from_s, lambda_2 over
the same window). The greedy and clairvoyant references plan with global knowledge and never
read the signalled states, so their episodes do not depend on T_up: they run once per mission
variant and serve every T_up (tests/learning/test_suite.py checks the independence).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from plmarl_sitl.config import PROJECT_SUITE, ConfigError, load_yaml
from plmarl_sitl.errors import UserError
from plmarl_sitl.learning.eval.evaluate import MethodRun, controller_factory, needed_policies, run_method
from plmarl_sitl.learning.eval.methods import GLOBAL_KNOWLEDGE
from plmarl_sitl.learning.eval.references import ABOUT, REFERENCES, best_reference, pairwise_wins
from plmarl_sitl.learning.eval.stats import compare, mean_ci95
from plmarl_sitl.learning.eval.transient import after_target_levels, failure_transient
from plmarl_sitl.learning.nn.features import FeatureScales
from plmarl_sitl.learning.nn.io import LoadedPolicy, load_policy
from plmarl_sitl.learning.train.seeds import EVAL_SEED_BASE, suite_twin_seed
from plmarl_sitl.mission import Mission, load_mission

# The time at which `failure_prob` fails a node: CoverageEnv's default `failure_at_s`,
# which `run_method` uses (a test pins the two together).
FAILURE_AT_S = 100.0
BATCH = 50  # parallel twin episodes per rollout (as `plmarl eval`)


@dataclass(frozen=True)
class Family:
    name: str
    about: str
    missions: tuple[str, ...]  # paths relative to the suite file
    tup: tuple[int, ...] = ()  # pinned T_up values; empty: the run's --tup
    failure_prob: float = field(default=0.0, metadata={"min": 0.0, "max": 1.0})
    # The second the family's missions fail their UAVs at (their `failures`), for the
    # failure transient; a family with failure_prob > 0 fails one at FAILURE_AT_S.
    failure_at_s: float | None = None

    def __post_init__(self) -> None:
        if not self.missions:
            raise ConfigError("missions", "list at least one mission")
        if any(t < 1 for t in self.tup):
            raise ConfigError("tup", "T_up values must be >= 1 s")


@dataclass(frozen=True)
class SuiteSpec:
    families: tuple[Family, ...]
    scaling: tuple[str, ...] = ()  # families plotted against N (Fig. 4b)

    def __post_init__(self) -> None:
        names = [f.name for f in self.families]
        for i, name in enumerate(names):
            if name in names[:i]:
                raise ConfigError(f"families[{i}].name", f"duplicate family {name!r}")
        for i, name in enumerate(self.scaling):
            if name not in names:
                raise ConfigError(f"scaling[{i}]", f"no family named {name!r}")


@dataclass(frozen=True)
class LoadedFamily:
    spec: Family
    missions: tuple[Mission, ...]

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def n_uavs(self) -> list[int]:
        return sorted({m.n_uavs for m in self.missions})


def load_suite(path: str | Path) -> tuple[SuiteSpec, dict[str, LoadedFamily]]:
    """The suite file and every family's missions (loaded and checked)."""
    path = Path(path)
    spec = load_yaml(SuiteSpec, path)
    # The project's own families are disconnected on purpose where they say so (thin_area's relay gap):
    # their reach warnings are not news to anyone; a suite file of a user's own warns as `load_mission` does.
    warn = path.resolve() != Path(PROJECT_SUITE).resolve()
    families = {
        f.name: LoadedFamily(f, tuple(load_mission(path.parent / m, warn=warn) for m in f.missions)) for f in spec.families
    }
    for fam in families.values():
        _require_one_clock(fam)
    return spec, families


def _require_one_clock(family: LoadedFamily) -> None:
    """A family's coverage traces are stacked episode by episode and averaged second by
    second, so its missions must share one episode length and time step (a family that
    mixed 300 s and 250 s missions used to stop with a numpy traceback after minutes)."""
    clocks = {(m.timing.episode_s, m.timing.dt_s) for m in family.missions}
    if len(clocks) > 1:
        each = ", ".join(f"{name} {m.timing.episode_s:g} s / dt {m.timing.dt_s:g} s"
                         for name, m in zip(family.spec.missions, family.missions, strict=True))
        raise UserError(f"suite family '{family.name}': its missions must share timing.episode_s and timing.dt_s "
                        f"(their traces are averaged second by second); got {each}")


def select(spec: SuiteSpec, text: str) -> list[str]:
    """Family names from 'all' or 'a,b,c' (suite order kept); one-line UserError otherwise."""
    names = [f.name for f in spec.families]
    wanted = [w.strip() for w in text.split(",") if w.strip()]
    if wanted == ["all"]:
        return names
    bad = [w for w in wanted if w not in names]
    if bad or not wanted:
        raise UserError(f"unknown suite family {', '.join(map(repr, bad)) or '(none)'}; choose from {', '.join(names)} or all")
    return [n for n in names if n in wanted]


def episodes_per_mission(episodes: int, n_missions: int) -> list[int]:
    """Episode i runs mission i mod n_missions."""
    return [len(range(v, episodes, n_missions)) for v in range(n_missions)]


def family_tups(family: LoadedFamily, tups: list[int]) -> list[int]:
    return list(family.spec.tup) or list(tups)


def failure_second(family: LoadedFamily) -> float | None:
    """The second the family's UAVs fail at (its failure_at_s, else FAILURE_AT_S when it
    draws failures); None for a family without failures."""
    return family.spec.failure_at_s or (FAILURE_AT_S if family.spec.failure_prob > 0 else None)


def load_policies(families: list[LoadedFamily], methods: list[str], directory: str | Path) -> dict[str, LoadedPolicy]:
    """The trained policies the methods need, from directory/<method>, each checked against
    every mission it will fly (area, vehicle, buffer length): PolicyFileError otherwise."""
    loaded: dict[str, LoadedPolicy] = {}
    checked: set = set()
    for m in (m for fam in families for m in fam.missions):
        key = (FeatureScales.from_mission(m), m.signalling.buffer_len)
        if key not in checked:
            checked.add(key)
            for meth in sorted(needed_policies(methods)):
                loaded.setdefault(meth, load_policy(Path(directory) / meth, m))
    return loaded


def twin_seeds(run_seed: int, episodes: int, family: LoadedFamily, batch: int = BATCH) -> list[list[int]]:
    """Every twin seed the family uses, per mission variant (all >= EVAL_SEED_BASE)."""
    return [
        [suite_twin_seed(run_seed, v, k) for k in range(math.ceil(e / batch))]
        for v, e in enumerate(episodes_per_mission(episodes, len(family.missions)))
    ]


def decisions(family: LoadedFamily, episodes: int, tups: list[int], methods: list[str]) -> int:
    """Agent-batch decisions the family costs (for the progress bar); the global-knowledge
    references run once."""
    per_tup = [m for m in methods if m not in GLOBAL_KNOWLEDGE]
    runs = len(per_tup) * len(family_tups(family, tups)) + sum(m in methods for m in GLOBAL_KNOWLEDGE)
    return runs * sum(
        e * math.ceil(m.timing.episode_s / m.timing.decision_every_s)
        for m, e in zip(family.missions, episodes_per_mission(episodes, len(family.missions)), strict=True)
    )


def _concat(runs: list[MethodRun]) -> MethodRun:
    return MethodRun(*(np.concatenate([getattr(r, k) for r in runs]) for k in ("coverage", "coverage_full", "lambda2", "trace")))


def run_family(
    family: LoadedFamily,
    loaded: dict[str, LoadedPolicy],
    methods: list[str],
    tups: list[int],
    episodes: int,
    run_seed: int,
    *,
    from_s: int = 50,
    on_decision: Callable[[int], None] | None = None,
) -> dict[tuple[str, int], MethodRun]:
    """{(method, tup): per-episode results over all the family's missions, in variant order}."""
    seeds = twin_seeds(run_seed, episodes, family)
    counts = episodes_per_mission(episodes, len(family.missions))
    assert all(s >= EVAL_SEED_BASE for v in seeds for s in v)
    fam_tups = family_tups(family, tups)

    def run(method: str, tup: int) -> MethodRun:
        make = controller_factory(method, loaded)
        parts = [
            run_method(m.with_tup(tup), make, e, s[0], batch=BATCH, from_s=from_s,
                       failure_prob=family.spec.failure_prob, on_decision=on_decision)
            for m, e, s in zip(family.missions, counts, seeds, strict=True) if e > 0
        ]
        return _concat(parts)

    runs: dict[tuple[str, int], MethodRun] = {}
    for method in (m for m in methods if m in GLOBAL_KNOWLEDGE):
        once = run(method, fam_tups[0])
        runs.update({(method, t): once for t in fam_tups})
    for tup in fam_tups:
        for method in methods:
            if method not in GLOBAL_KNOWLEDGE:
                runs[(method, tup)] = run(method, tup)
    return runs


def summarise(family: LoadedFamily, runs: dict[tuple[str, int], MethodRun], methods: list[str], tups: list[int]) -> dict:
    """Rows, p-values and (for failure families) transients of one family."""
    n = family.n_uavs
    rows, p_values, transients, references = [], [], [], []
    for tup in family_tups(family, tups):
        best = best_reference({m: (runs[(m, tup)].coverage, runs[(m, tup)].trace) for m in methods})
        if best is not None:
            references.append({"family": family.name, "tup": tup, "best": best.label(), "shares": best.shares(),
                               "coverage_mean": float(best.coverage.mean()),
                               "wins": pairwise_wins({m: runs[(m, tup)].coverage for m in methods})})
        for method in methods:
            r = runs[(method, tup)]
            mean, ci = mean_ci95(r.coverage)
            lam, lam_ci = mean_ci95(r.lambda2)
            row = {"family": family.name, "n_uavs": n[0] if len(n) == 1 else n, "tup": tup, "method": method,
                   "episodes": int(r.coverage.size), "coverage_mean": mean, "coverage_ci95": list(ci),
                   "coverage_full_mean": float(r.coverage_full.mean()), "lambda2_mean": lam, "lambda2_ci95": list(lam_ci),
                   # Every episode's value, in the family's episode order (the same for every method), at
                   # full precision (a paired test counts exact ties), so any two methods can be compared
                   # after the run (`plmarl suite --compare`).
                   "coverage_per_episode": [float(x) for x in r.coverage]}
            if best is not None:
                fm, fci = mean_ci95(r.coverage / np.maximum(best.coverage, 1e-9))
                row.update({"fraction_of_best_mean": fm, "fraction_of_best_ci95": list(fci), "best_reference": best.label(),
                            "best_reference_coverage_mean": float(best.coverage.mean())})
            if method != "pl-marl" and "pl-marl" in methods:
                c = compare(runs[("pl-marl", tup)].coverage, r.coverage)
                row.update({"p_pl_marl_vs": c["p"], "p_paired_pl_marl_vs": c["p_paired"],
                            "pl_marl_wins_losses": [c["wins"], c["losses"]]})
                p_values.append({"family": family.name, "tup": tup, "method": "pl-marl", "versus": method, **c})
            rows.append(row)
            horizon = r.trace.shape[1]
            fail_s = failure_second(family)
            if fail_s is not None and best is not None and fail_s < horizon:
                t = failure_transient(r.trace, best.trace, int(fail_s))
                after = after_target_levels(r.trace, int(fail_s))
                transients.append({"family": family.name, "tup": tup, "method": method, **t,
                                   "after_target_per_episode": [None if np.isnan(x) else float(x) for x in after]})
    traces = {f"{m}@{t}": [round(float(x), 4) for x in r.trace.mean(0)] for (m, t), r in runs.items()}
    return {"rows": rows, "p_values": p_values, "transients": transients, "references": references,
            "traces": {family.name: traces}}


def run_suite(
    families: list[LoadedFamily],
    loaded: dict[str, LoadedPolicy],
    methods: list[str],
    tups: list[int],
    episodes: int,
    run_seed: int,
    *,
    from_s: int = 50,
    on_decision: Callable[[int], None] | None = None,
    on_family: Callable[[str], None] | None = None,
) -> dict:
    """The whole result document (see `plmarl suite --help`), minus provenance."""
    if episodes < 2:
        raise UserError("--episodes must be >= 2 (a confidence interval needs two episodes)")
    out: dict = {"episodes": episodes, "seed": run_seed, "from_s": from_s, "methods": methods, "tups": tups,
                 "eval_seed_base": EVAL_SEED_BASE, "families": [], "rows": [], "p_values": [], "transients": [],
                 "references": [], "reference_about": {r: ABOUT[r] for r in REFERENCES if r in methods}, "traces": {}}
    for fam in families:
        if on_family:
            on_family(fam.name)
        seeds = twin_seeds(run_seed, episodes, fam)
        out["families"].append({
            "name": fam.name, "about": fam.spec.about, "missions": [m.name for m in fam.missions],
            "n_uavs": fam.n_uavs, "tup": family_tups(fam, tups), "failure_prob": fam.spec.failure_prob,
            "episodes_per_mission": episodes_per_mission(episodes, len(fam.missions)),
            "twin_seeds": seeds,
        })
        runs = run_family(fam, loaded, methods, tups, episodes, run_seed, from_s=from_s, on_decision=on_decision)
        part = summarise(fam, runs, methods, tups)
        for key in ("rows", "p_values", "transients", "references"):
            out[key] += part[key]
        out["traces"].update(part["traces"])
    return out
