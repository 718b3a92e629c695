"""Per-episode failure diagnostics in the digital twin: coverage and failure declarations, per
suite family, T_up and method (issue 24's study bench, sessions 25-27).

Why: each study of the failure re-plans wrote its own runner that flew a suite family's
episodes and read every agent's knowledge of failures (`env.gossip`) against the truth
(`env.alive`). This is that loop, once. The episodes are exactly `plmarl suite`'s: mission
variant v of a family flies its share of the episodes (`suite.episodes_per_mission`) in twin
batches of `suite.BATCH` seeded by `suite.twin_seeds`, so a method's `coverage` here equals
the suite's `coverage_per_episode` for the same family, seed, T_up and episodes.

Per episode (a "survivor" is a UAV alive at that moment; a copy is one UAV's knowledge):

* coverage: mean C(t) for t > --from-s (the suite's coverage);
* after_failure30: mean C(t) from 30 s after the family's failure (the suite's
  after_target_per_episode; None on families without a failure);
* false_ids: live UAVs some survivor declared failed at some decision, each counted once;
* false_end: (survivor, live teammate) pairs held failed at the end;
* dead: UAVs dead at the end; dead_declared: those some survivor declared failed (at any time);
* undeclared_end: dead UAVs no survivor holds failed at the end;
* detect_s: mean delay (s) from each declared dead UAV's failure to its first declaration by a
  survivor (None: none declared). A controller declares at its decisions, so this is read
  right after each decision;
* split_share: share of the seconds after --from-s with lambda_2 < SPLIT_LAMBDA2 (the live
  swarm split in two or more parts; the window of the suite's lambda_2).

`--set key=value` changes every mission of the run: any mission key as in its YAML (dotted for a
nested one), the value checked by the mission schema itself (`apply_sets`); a method that sets the same key itself (service-resolve, pl-marl-resolve) keeps its own.
greedy and clairvoyant ignore signalling, so as in the suite they fly once per family and serve
every T_up; they read true states and declare nothing, so their dead UAVs count as undeclared.
With two or more methods, each is compared with the first on the same episodes
(`stats.compare`: paired Wilcoxon, Mann-Whitney U, wins/losses).
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import torch
import yaml

from plmarl_sitl.cmdline import comma_list, progress, table_console
from plmarl_sitl.config import PROJECT_POLICIES, PROJECT_SUITE, ConfigError, to_dict
from plmarl_sitl.errors import UserError, run_reporting
from plmarl_sitl.learning.eval.evaluate import controller_factory
from plmarl_sitl.learning.eval.methods import GLOBAL_KNOWLEDGE, parse_methods
from plmarl_sitl.learning.eval.report import comparison_text
from plmarl_sitl.learning.eval.stats import compare
from plmarl_sitl.learning.eval.suite import (
    BATCH,
    LoadedFamily,
    decisions,
    episodes_per_mission,
    failure_second,
    family_tups,
    load_policies,
    load_suite,
    select,
    twin_seeds,
)
from plmarl_sitl.learning.eval.transient import TARGET_S, after_target_levels
from plmarl_sitl.learning.nn.io import LoadedPolicy
from plmarl_sitl.learning.pipeline import git_commit
from plmarl_sitl.machine import machine_info
from plmarl_sitl.mission import Mission, mission_from_dict
from plmarl_sitl.twin.env import CoverageEnv
from plmarl_sitl.twin.rollout import MakeController

PROG = "python -m plmarl_sitl.bench.episodes"
SPLIT_LAMBDA2 = 1e-6  # lambda_2 below this: the live swarm's graph is disconnected
MEASURES = ("coverage", "after_failure30", "false_ids", "false_end", "dead", "dead_declared", "undeclared_end",
            "detect_s", "split_share")


# ---------------------------------------------------------------------- mission variants (--set)
# A value is checked by the mission schema itself (config.from_dict: types, choices, bounds, cross-field
# checks), on a mission with nothing else set, so a bad one fails before any episode flies.
PROBE = Mission(name="set")


def parse_sets(items: list[str]) -> dict[str, object]:
    """['key=value', ...] (key a mission key as in its YAML, dotted for nested ones; value YAML) ->
    {key: value}; a one-line UserError for an unknown key or a bad value."""
    out: dict[str, object] = {}
    for item in items:
        key, eq, text = item.partition("=")
        key, text = key.strip(), text.strip()
        if not eq or not key:
            raise UserError(f"--set {item!r}: give key=value, a mission key as in its YAML (docs/MISSIONS.md)")
        try:
            value = yaml.safe_load(text)
        except yaml.YAMLError:
            value = text
        try:
            apply_sets(PROBE, {key: value})
        except ConfigError as exc:
            if exc.reason.startswith("unknown key"):
                raise UserError(f"--set {item!r}: unknown key {key!r} {exc.reason.removeprefix('unknown key').strip()}") from None
            raise UserError(f"--set {item!r}: bad value {text!r} for {key}: {exc.reason}") from None
        out[key] = value
    return out


def apply_sets(mission: Mission, sets: dict[str, object]) -> Mission:
    """The mission with each dotted key set, rebuilt through the schema (ConfigError naming the key)."""
    data = to_dict(mission)
    for key, value in sets.items():
        *parents, leaf = key.split(".")
        node = data
        for i, part in enumerate(parents):
            if not isinstance(node.get(part), dict):
                raise ConfigError(".".join(parents[: i + 1]), "unknown key (not a section of the mission)")
            node = node[part]
        node[leaf] = value
    return mission_from_dict(data)


# ---------------------------------------------------------------------- one batch of episodes
class Declarations:
    """What the survivors' copies declared, booked whenever they may have changed."""

    def __init__(self, batch: int, n: int) -> None:
        self.false_ids = torch.zeros(batch, n, dtype=torch.bool)  # live UAVs ever declared by a survivor
        self.first = torch.full((batch, n), float("nan"), dtype=torch.float64)  # first declaration of a dead UAV, s

    def look(self, env: CoverageEnv, t: int) -> None:
        alive = env.alive
        held = held_pairs(env).any(1)  # (B, N): UAV j held failed by some survivor
        self.false_ids |= held & alive
        self.first = torch.where(held & ~alive & self.first.isnan(), torch.full_like(self.first, float(t)), self.first)


def held_pairs(env: CoverageEnv) -> torch.Tensor:
    """(B, N, N) bool [i, j]: survivor i holds teammate j failed."""
    eye = torch.eye(env.n, dtype=torch.bool)
    return env.gossip.failed & env.alive.unsqueeze(-1) & ~eye


def fly_batch(mission: Mission, make: MakeController, episodes: int, seed: int, *, failure_prob: float, from_s: int,
              fail_s: float | None, on_decision: Callable[[int], None] | None = None) -> dict[str, np.ndarray]:
    """One twin batch as `twin/rollout.py::rollout` builds it, with the declarations booked."""
    with torch.inference_mode():  # as rollout: the env and controller are made inside it too
        env = CoverageEnv(mission, episodes, seed, track_lambda2=True, failure_prob=failure_prob)
        ctl = make(env)
        ctl.reset()
        obs = env.observe()
        book = Declarations(episodes, env.n)
        cover, lam = [], []
        while not env.done:
            accel = ctl.act(obs)
            book.look(env, obs.t)  # a controller declares at its decisions, into env.gossip
            obs, _, info = env.step(accel)
            book.look(env, obs.t)  # and knowledge received at the instants inside the step
            cover.append(info.coverage)
            lam.append(info.lambda2)
            if on_decision:
                on_decision(episodes)
    trace = torch.cat(cover, -1)
    alive, pairs = env.alive, held_pairs(env)
    dead = ~alive
    declared_dead = dead & ~book.first.isnan()
    delay = torch.where(declared_dead, book.first - env.fail_at.double(), torch.nan)
    return {
        "coverage": trace[:, from_s:].mean(-1).numpy(),  # the suite's op for op (evaluate.run_method)
        "after_failure30": (after_target_levels(trace.numpy(), int(fail_s)) if fail_s is not None
                            else np.full(episodes, np.nan)),
        "false_ids": book.false_ids.sum(-1).numpy(),
        "false_end": (pairs & alive.unsqueeze(1)).sum((-1, -2)).numpy(),
        "dead": dead.sum(-1).numpy(),
        "dead_declared": declared_dead.sum(-1).numpy(),
        "undeclared_end": (dead & ~pairs.any(1)).sum(-1).numpy(),
        "detect_s": nanmean_rows(delay.numpy()),
        "split_share": (torch.cat(lam, -1)[:, from_s:] < SPLIT_LAMBDA2).double().mean(-1).numpy(),  # the suite's window
    }


def nanmean_rows(x: np.ndarray) -> np.ndarray:
    """Mean of each row's finite values (nan for a row with none), without numpy's warning."""
    finite = np.isfinite(x)
    total = np.where(finite, x, 0.0).sum(-1)
    count = finite.sum(-1)
    return np.where(count > 0, total / np.maximum(count, 1), np.nan)


# ---------------------------------------------------------------------- a family's cells
def run_cell(family: LoadedFamily, make: MakeController, tup: int, episodes: int, run_seed: int, sets: dict[str, object],
             *, from_s: int, on_decision: Callable[[int], None] | None = None) -> dict[str, np.ndarray]:
    """Every episode of one method at one T_up, in the suite's episode order."""
    counts = episodes_per_mission(episodes, len(family.missions))
    seeds = twin_seeds(run_seed, episodes, family)
    parts = []
    for mission, e, batch_seeds in zip(family.missions, counts, seeds, strict=True):
        m = apply_sets(mission, sets).with_tup(tup)
        for seed, lo in zip(batch_seeds, range(0, e, BATCH), strict=True):
            parts.append(fly_batch(m, make, min(BATCH, e - lo), seed, failure_prob=family.spec.failure_prob,
                                   from_s=from_s, fail_s=failure_second(family), on_decision=on_decision))
    return {k: np.concatenate([p[k] for p in parts]) for k in MEASURES}


def run_family(family: LoadedFamily, loaded: dict[str, LoadedPolicy], methods: list[str], tups: list[int], episodes: int,
               run_seed: int, sets: dict[str, object], *, from_s: int,
               on_decision: Callable[[int], None] | None = None) -> dict[tuple[str, int], dict[str, np.ndarray]]:
    """{(method, T_up): per-episode measures}; a global-knowledge reference flies once (as the suite)."""
    fam_tups = family_tups(family, tups)
    runs: dict[tuple[str, int], dict[str, np.ndarray]] = {}
    for method in methods:
        make = controller_factory(method, loaded)
        for tup in fam_tups:
            if method in GLOBAL_KNOWLEDGE and tup != fam_tups[0]:
                runs[(method, tup)] = runs[(method, fam_tups[0])]
                continue
            runs[(method, tup)] = run_cell(family, make, tup, episodes, run_seed, sets, from_s=from_s,
                                           on_decision=on_decision)
    return runs


def as_json(x: np.ndarray) -> list:
    """Per-episode values for JSON: counts as ints, nan as None."""
    if np.issubdtype(x.dtype, np.integer):
        return [int(v) for v in x]
    return [None if not np.isfinite(v) else float(v) for v in x]


def mean_of(x: np.ndarray) -> float | None:
    finite = x[np.isfinite(x)]
    return float(finite.mean()) if finite.size else None


def comparisons(family: str, tup: int, runs: dict, methods: list[str]) -> list[dict]:
    """Each method against the first on the same episodes: coverage, and from 30 s after the failure."""
    first, out = methods[0], []
    for method in methods[1:]:
        row = {"family": family, "tup": tup, "method": method, "versus": first}
        for key in ("coverage", "after_failure30"):
            a, b = runs[(method, tup)][key], runs[(first, tup)][key]
            both = np.isfinite(a) & np.isfinite(b)
            if both.any():
                row[key] = {"difference": float((a[both] - b[both]).mean()), **compare(a[both], b[both])}
        out.append(row)
    return out


def summarise(family: LoadedFamily, runs: dict, methods: list[str], tups: list[int]) -> tuple[list[dict], list[dict]]:
    rows, comps = [], []
    for tup in family_tups(family, tups):
        for method in methods:
            r = runs[(method, tup)]
            rows.append({"family": family.name, "tup": tup, "method": method, "episodes": int(r["coverage"].size),
                         "means": {k: mean_of(r[k].astype(np.float64)) for k in MEASURES},
                         "per_episode": {k: as_json(r[k]) for k in MEASURES}})
        if len(methods) > 1:
            comps += comparisons(family.name, tup, runs, methods)
    return rows, comps


# ---------------------------------------------------------------------- output
COLUMNS = (("coverage", "coverage", 3), ("after_failure30", f"fail+{TARGET_S}s", 3), ("false_ids", "false ids", 2),
           ("false_end", "false end", 2), ("dead", "dead", 2), ("dead_declared", "declared", 2),
           ("undeclared_end", "undeclared", 2), ("detect_s", "detect s", 1), ("split_share", "split", 3))


def _cell(v: float | None, digits: int) -> str:
    return "-" if v is None else f"{v:.{digits}f}"


def print_table(doc: dict) -> None:
    from rich.table import Table

    t = Table(title=f"per-episode failure diagnostics, means over {doc['episodes']} episodes (seed {doc['seed']}"
              + (f", {', '.join(f'{k}={v}' for k, v in doc['set'].items())}" if doc["set"] else "") + ")")
    for c in ("family", "T_up", "method", *(label for _, label, _ in COLUMNS)):
        t.add_column(c)
    for r in doc["rows"]:
        t.add_row(r["family"], str(r["tup"]), r["method"], *(_cell(r["means"][k], d) for k, _, d in COLUMNS))
    console = table_console()
    console.print(t)
    for line in comparison_lines(doc):
        console.print(line)


def comparison_lines(doc: dict) -> list[str]:
    lines = []
    for c in doc["comparisons"]:
        parts = [f"{key} {c[key]['difference']:+.4f}, {comparison_text(c[key])}" for key in ("coverage", "after_failure30")
                 if key in c]
        lines.append(f"{c['family']} T_up {c['tup']}: {c['method']} - {c['versus']}: " + "; ".join(parts))
    if lines:
        lines.insert(0, "paired on the same episodes: difference, MWU p / paired Wilcoxon p (wins/losses)")
    return lines


def results_md(doc: dict) -> str:
    head = ["family", "T_up", "method", *(label for _, label, _ in COLUMNS)]
    lines = [f"# Per-episode failure diagnostics\n\n`{doc['command']}` (commit {doc['commit']}, {doc['date']}; "
             f"{doc['machine']})\n", f"Means over {doc['episodes']} episodes per cell; definitions in "
             "plmarl_sitl/bench/episodes.py; every episode's value in results.json.\n",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in doc["rows"]:
        cells = [r["family"], str(r["tup"]), r["method"], *(_cell(r["means"][k], d) for k, _, d in COLUMNS)]
        lines.append("| " + " | ".join(cells) + " |")
    comp = comparison_lines(doc)
    return "\n".join(lines + ([""] + [f"* {x}" if i else x for i, x in enumerate(comp)] if comp else [])) + "\n"


# ---------------------------------------------------------------------- command line
def parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog=PROG, description=__doc__,  # what each measure is, and how the episodes are the suite's
        epilog="example:\n  OMP_NUM_THREADS=1 python -m plmarl_sitl.bench.episodes failure_2of6,failure_transit "
        "--methods pl-marl,service --tup 15,50 --episodes 30 --seed 38 --set failure_replan=resolve --out runs/episodes",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("families", help="a comma list of suite family names (plmarl suite --list), or all")
    ap.add_argument("--methods", default="pl-marl,service", help="comma list, the first is the one compared against "
                    "(plmarl suite's methods; default: pl-marl,service)")
    ap.add_argument("--tup", type=comma_list(int, "T_up", positive=True), default=[15, 50],
                    help="comma list of T_up values for families that pin none, as plmarl suite (default: 15,50)")
    ap.add_argument("--episodes", type=int, default=30, help="episodes per family and T_up (default: 30)")
    ap.add_argument("--seed", type=int, default=0, help="suite run seed: the suite's evaluation seeds (default: 0)")
    ap.add_argument("--from-s", type=int, default=50, help="coverage counts t > this (default: 50, as the suite)")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="change every mission (repeatable): any mission key as in its YAML, dotted for a nested one, "
                    "e.g. failure_replan=resolve, transit_plan_m=300, signalling.drop_after_missed=2 (docs/MISSIONS.md)")
    ap.add_argument("--suite-file", default=str(PROJECT_SUITE), help="default: the project's missions/suite/suite.yaml")
    ap.add_argument("--policies", default=str(PROJECT_POLICIES), help="directory of <method>/ policies "
                    "(default: the project's policies/)")
    ap.add_argument("--json", action="store_true", help="print exactly one JSON object on stdout")
    ap.add_argument("--out", default=None, metavar="DIR", help="write results.json and results.md here")
    return ap


def run(args: argparse.Namespace) -> int:
    try:
        methods = parse_methods(args.methods)
    except ValueError as exc:
        raise UserError(str(exc)) from None
    sets = parse_sets(args.set)
    if args.episodes < 1:
        raise UserError("--episodes must be >= 1")
    torch.set_num_threads(1)
    spec, families = load_suite(args.suite_file)
    chosen = [families[n] for n in select(spec, args.families)]
    loaded = load_policies(chosen, methods, args.policies)
    # Read at the start: a long run can outlast a commit made beside it.
    commit, started, t0 = git_commit(), datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"), time.time()
    rows, comps = [], []
    with progress(disable=args.json) as bar:
        task = bar.add_task("episodes", total=sum(decisions(f, args.episodes, args.tup, methods) for f in chosen))
        for fam in chosen:
            bar.update(task, description=f"episodes {fam.name} (seed {args.seed})")
            runs = run_family(fam, loaded, methods, args.tup, args.episodes, args.seed, sets, from_s=args.from_s,
                              on_decision=lambda b: bar.advance(task, b))
            r, c = summarise(fam, runs, methods, args.tup)
            rows += r
            comps += c
    doc = {"command": PROG + " " + " ".join(shlex.quote(a) for a in sys.argv[1:]), "seed": args.seed,
           "commit": commit, "machine": machine_info(), "date": started, "wall_s": round(time.time() - t0, 1),
           "episodes": args.episodes, "from_s": args.from_s, "methods": methods, "tups": args.tup, "set": sets,
           "suite_file": args.suite_file, "policies": args.policies, "split_lambda2": SPLIT_LAMBDA2,
           "families": [{"name": f.name, "tup": family_tups(f, args.tup), "failure_at_s": failure_second(f),
                         "failure_prob": f.spec.failure_prob, "missions": [m.name for m in f.missions],
                         "episodes_per_mission": episodes_per_mission(args.episodes, len(f.missions)),
                         "twin_seeds": twin_seeds(args.seed, args.episodes, f)} for f in chosen],
           "rows": rows, "comparisons": comps}
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "results.json").write_text(json.dumps(doc, indent=1))
        (out / "results.md").write_text(results_md(doc))
    if args.json:
        print(json.dumps(doc))
    else:
        print_table(doc)
    return 0


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    return run_reporting(PROG, lambda: run(args))


if __name__ == "__main__":
    sys.exit(main())
