"""The held-out suite: seed split, family selection, the transient's definitions, and
`plmarl suite --json` end to end on tiny exported policies and short missions."""

from __future__ import annotations

import inspect
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from plmarl_sitl.cli import main
from plmarl_sitl.errors import UserError
from plmarl_sitl.learning.eval.evaluate import controller_factory, run_method
from plmarl_sitl.learning.eval.suite import FAILURE_AT_S, episodes_per_mission, load_suite, select, twin_seeds
from plmarl_sitl.learning.eval.transient import failure_transient, reach_times, settle_times
from plmarl_sitl.learning.nn import Actor, BeliefTracker, DeployedPolicy, FeatureScales, make_predictor
from plmarl_sitl.learning.nn.io import export_policy
from plmarl_sitl.learning.train.mappo import Args, train
from plmarl_sitl.learning.train.seeds import EVAL_SEED_BASE, suite_twin_seed, training_twin_seed
from plmarl_sitl.mission import load_mission
from plmarl_sitl.twin.env import CoverageEnv

ROOT = Path(__file__).resolve().parents[2]
PAPER = ROOT / "missions" / "paper_urban.yaml"
SUITE = ROOT / "missions" / "suite" / "suite.yaml"


# ---------------------------------------------------------------------- seeds
def test_training_refuses_evaluation_seeds() -> None:
    assert training_twin_seed(EVAL_SEED_BASE - 1) == EVAL_SEED_BASE - 1
    for bad in (EVAL_SEED_BASE, EVAL_SEED_BASE + 12345, -1):
        with pytest.raises(UserError, match="evaluation"):
            training_twin_seed(bad)


def test_mappo_rollout_seeds_of_the_shipped_runs_are_training_seeds() -> None:
    # plmarl train --seed s: MAPPO rollout twins use s * 100_003 + iteration (Table I: 63 iterations).
    for s in (1, 2, 3, 9_000):
        assert all(training_twin_seed(s * 100_003 + it) for it in range(63))


def test_mappo_with_a_seed_reaching_the_evaluation_range_fails_loudly(tmp_path: Path) -> None:
    args = Args(method="tag-mappo", mission=str(PAPER), seed=10_000, episodes=2, num_envs=2, imitation_rounds=0,
                out=str(tmp_path / "mappo"))
    with pytest.raises(UserError, match="reserved for the held-out evaluation suite"):
        train(args)


def test_every_suite_seed_is_in_the_evaluation_range() -> None:
    spec, families = load_suite(SUITE)
    assert {f.name for f in spec.families} >= {"paper", "random", "moved", "launch", "rpgm", "n8", "n12", "n20", "failure"}
    for run_seed in (0, 7, 99_999):
        seeds = [s for fam in families.values() for v in twin_seeds(run_seed, 200, fam) for s in v]
        assert min(seeds) >= EVAL_SEED_BASE
    assert suite_twin_seed(0, 0, 0) == EVAL_SEED_BASE
    with pytest.raises(UserError):
        suite_twin_seed(-1, 0)
    with pytest.raises(UserError):
        suite_twin_seed(0, 0, 100)  # would run into the next mission variant's seeds


def test_episodes_are_spread_over_a_familys_missions() -> None:
    assert episodes_per_mission(30, 4) == [8, 8, 7, 7]
    assert episodes_per_mission(2, 4) == [1, 1, 0, 0]
    assert sum(episodes_per_mission(31, 3)) == 31


def test_unknown_family_is_a_one_line_error(capsys: pytest.CaptureFixture[str]) -> None:
    spec, _ = load_suite(SUITE)
    assert select(spec, "all") == [f.name for f in spec.families]
    assert select(spec, "n20,random") == ["random", "n20"]  # suite order
    with pytest.raises(UserError, match="unknown suite family 'nope'"):
        select(spec, "random,nope")
    assert main(["suite", "nope", "--suite-file", str(SUITE)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "nope" in err and "random" in err


# ---------------------------------------------------------------------- twin facts the suite relies on
def test_failure_time_is_the_twins() -> None:
    assert inspect.signature(CoverageEnv).parameters["failure_at_s"].default == FAILURE_AT_S


@pytest.mark.parametrize("method", ["greedy", "clairvoyant"])
def test_global_knowledge_references_do_not_depend_on_tup(tmp_path: Path, method: str) -> None:
    m = _short_mission(tmp_path, 30)
    make = controller_factory(method, {})
    a = run_method(m.with_tup(5), make, 2, EVAL_SEED_BASE, from_s=10)
    b = run_method(m.with_tup(50), make, 2, EVAL_SEED_BASE, from_s=10)
    np.testing.assert_array_equal(a.trace, b.trace)
    np.testing.assert_array_equal(a.lambda2, b.lambda2)


# ---------------------------------------------------------------------- transient definitions
def test_transient_trough_and_plateau_on_a_known_trace() -> None:
    t = np.arange(1, 201)
    reference = np.where(t < 100, 1.0, 0.8)[None, :]
    # Drops to 0.5 at t = 100, recovers linearly to 0.8 at t = 130, then flat.
    c = np.where(t < 100, 0.9, np.minimum(0.5 + 0.01 * (t - 100), 0.8))[None, :]
    res = failure_transient(c, reference, 100)
    assert res["trough_mean"] == pytest.approx(0.5)
    assert res["pre_failure_mean"] == pytest.approx(0.9)
    assert res["reference_post_level_mean"] == pytest.approx(0.8)
    # First s with mean(c[100+s .. 109+s]) >= 0.76: 0.5 + 0.01 (s + 4.5) >= 0.76 -> s = 21.5 -> 22; it stays.
    assert res["reach_s_median"] == 22 and res["plateau_s_median"] == 22
    assert res["reach_within_target_share"] == 1.0 and res["plateau_within_target_share"] == 1.0
    assert res["plateau_never"] == 0
    # Holds 0.8 for 10 s, dips to 0.5 for t in [110, 140), back to 0.8: reaches at once, settles after the dip.
    dip = np.where((t >= 110) & (t < 140), 0.5, 0.8)[None, :]
    level = np.array([0.8])
    assert reach_times(dip, level, 100)[0] == 0
    # A window holding k dip seconds has mean 0.8 - 0.03 k >= 0.76 only for k <= 1: from [139, 149) on (s = 39).
    assert settle_times(dip, level, 100)[0] == 39
    assert np.isnan(reach_times(np.full((1, 200), 0.3), level, 100)).all()
    assert np.isnan(settle_times(np.full((1, 200), 0.3), level, 100)).all()


# ---------------------------------------------------------------------- end to end
def _short_mission(tmp_path: Path, episode_s: int, name: str = "short", extra: str = ""):  # noqa: ANN202
    path = tmp_path / f"{name}.yaml"
    path.write_text(f"extends: {PAPER}\nname: {name}\ntiming: {{episode_s: {episode_s}}}\n{extra}")
    return load_mission(path)


def test_suite_json_end_to_end(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    mission = load_mission(PAPER)
    scales = FeatureScales.from_mission(mission)
    torch.manual_seed(0)
    for method, kind in (("pl-marl", "mlp"), ("tag-mappo", "hold")):
        export_policy(tmp_path / "pol" / method, BeliefTracker(make_predictor(kind), 10, 1.0),
                      DeployedPolicy(Actor(), *scales), {"method": method, "seed": 0})
    _short_mission(tmp_path, 20, "short_a")
    _short_mission(tmp_path, 20, "short_b", "launch: {north_m: 150, east_m: 150}\n")
    _short_mission(tmp_path, 20, "short_n6", "n_uavs: 6\nusers: {count: 360, layout: lattice, cluster_centers: []}\n")
    _short_mission(tmp_path, 140, "fail")  # failure at 100 s, 10 s of the window from 30 s after it
    (tmp_path / "suite.yaml").write_text(
        "families:\n"
        "  - {name: two, about: two variants, missions: [short_a.yaml, short_b.yaml]}\n"
        "  - {name: six, about: N = 6, missions: [short_n6.yaml], tup: [5]}\n"
        "  - {name: fail, about: failure, missions: [fail.yaml], tup: [15], failure_prob: 1.0}\n"
        "scaling: [two, six]\n"
    )
    methods = ["pl-marl", "tag-mappo", "dead-reckoning", "service", "greedy", "clairvoyant"]
    rc = main(["suite", "all", "--suite-file", str(tmp_path / "suite.yaml"), "--methods", ",".join(methods),
               "--tup", "5,50", "--episodes", "2", "--from-s", "5", "--policies", str(tmp_path / "pol"),
               "--out", str(tmp_path / "out"), "--json"])
    assert rc == 0
    doc = json.loads(capsys.readouterr().out)
    assert "traces" not in doc and doc["episodes"] == 2
    cells = [("two", 5), ("two", 50), ("six", 5), ("fail", 15)]
    assert [(r["family"], r["tup"]) for r in doc["rows"]] == [c for c in cells for _ in methods]
    for r in doc["rows"]:
        assert r["episodes"] == 2 and r["coverage_ci95"][0] <= r["coverage_mean"] <= r["coverage_ci95"][1]
        assert "fraction_of_best_mean" in r and r["lambda2_ci95"][0] <= r["lambda2_mean"] <= r["lambda2_ci95"][1]
        assert ("p_pl_marl_vs" in r) == ("p_paired_pl_marl_vs" in r) == (r["method"] != "pl-marl")
        if "pl_marl_wins_losses" in r:
            assert sum(r["pl_marl_wins_losses"]) <= r["episodes"]
        if r["method"] in ("service", "greedy", "clairvoyant"):  # a reference never exceeds the best one
            assert r["fraction_of_best_mean"] <= 1.0 + 1e-9
    # The best reference per (family, T_up), named with how often each one was best.
    refs = {(b["family"], b["tup"]): b for b in doc["references"]}
    assert set(refs) == set(cells)
    for (fam, tup), b in refs.items():
        assert sum(b["shares"].values()) == pytest.approx(1.0)
        by = {r["method"]: r for r in doc["rows"] if (r["family"], r["tup"]) == (fam, tup)}
        assert b["coverage_mean"] >= max(by[m]["coverage_mean"] for m in ("service", "greedy", "clairvoyant")) - 1e-9
        assert all(r["best_reference"] == b["best"] for r in by.values())
        assert set(b["wins"]) >= {"clairvoyant>greedy", "clairvoyant>service"}
    assert set(doc["reference_about"]) == {"service", "greedy", "clairvoyant"}
    assert {r["n_uavs"] for r in doc["rows"] if r["family"] == "six"} == {6}
    assert len(doc["p_values"]) == len(cells) * (len(methods) - 1)
    assert [t["method"] for t in doc["transients"]] == methods
    assert all(t["family"] == "fail" and t["failure_at_s"] == 100 for t in doc["transients"])
    fams = {f["name"]: f for f in doc["families"]}
    assert fams["two"]["episodes_per_mission"] == [1, 1] and fams["fail"]["tup"] == [15]
    assert min(s for f in doc["families"] for v in f["twin_seeds"] for s in v) >= EVAL_SEED_BASE
    out = tmp_path / "out"
    for png in ("coverage_vs_tup.png", "coverage_vs_n.png", "failure_transient.png", "lambda2.png"):
        assert (out / png).stat().st_size > 1000
    md = (out / "results.md").read_text()
    assert "## Summary" in md and "## Failure transient" in md and "best reference" in md
    assert "not a ceiling" in md  # the report says what a reference is
    assert set(json.loads((out / "results.json").read_text())["traces"]) == {"two", "six", "fail"}
    # Every episode's value is kept, so any pair compares later: PL-MARL against service, read
    # back from results.json, gives the run's own paired figures exactly.
    assert all(len(r["coverage_per_episode"]) == r["episodes"] for r in doc["rows"])
    assert all(len(t["after_target_per_episode"]) == 2 for t in doc["transients"])
    capsys.readouterr()
    assert main(["suite", "--results", str(out), "--compare", "pl-marl,service", "--json"]) == 0
    later = json.loads(capsys.readouterr().out)["comparison"]
    ran = {(p["family"], p["tup"]): p for p in doc["p_values"] if p["versus"] == "service"}
    assert [(c["family"], c["tup"]) for c in later] == cells
    for c in later:
        assert {k: c[k] for k in ("p", "p_paired", "wins", "losses")} == {k: ran[(c["family"], c["tup"])][k] for k in ("p", "p_paired", "wins", "losses")}
    assert [("after_failure" in c) for c in later] == [False, False, False, True]


def test_compare_says_what_is_wrong(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    row = {"family": "f", "tup": 15, "episodes": 2, "coverage_mean": 0.5}
    old = {"seed": 0, "from_s": 50, "methods": ["a", "b"], "rows": [{**row, "method": "a"}, {**row, "method": "b"}]}
    (tmp_path / "results.json").write_text(json.dumps(old))
    (tmp_path / "bad.json").write_text("{not json")
    for argv, says in (
        (["--results", str(tmp_path), "--compare", "a,b"], "keeps no per-episode values"),
        (["--results", str(tmp_path), "--compare", "a,c"], "method 'c' is not in this run (it ran: a, b)"),
        (["--results", str(tmp_path / "bad.json"), "--compare", "a,b"], "is not a suite result document"),
        (["--results", str(tmp_path / "none"), "--compare", "a,b"], "no suite results at"),
        (["--results", str(tmp_path)], "name the two methods"),
        (["--results", str(tmp_path), "--compare", "a"], "two different methods"),
        (["fail", "--methods", "pl-marl,service", "--compare", "pl-marl,greedy"], "both methods must be among --methods"),
    ):
        assert main(["suite", *argv]) == 2, argv
        err = capsys.readouterr().err
        assert says in err and "Traceback" not in err and len(err.strip().splitlines()) == 1, err


def test_the_defaults_are_the_projects_files_from_any_directory(tmp_path: Path) -> None:
    # Run outside the checkout, `plmarl suite` and `plmarl eval` used to look for ./missions/suite
    # and ./policies and stopped with "cannot read file"; their defaults are the project's own.
    import subprocess
    import sys

    def plmarl(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "plmarl_sitl.cli", *args], capture_output=True, text=True,
                              timeout=300, cwd=tmp_path)

    r = plmarl("suite", "--list")
    assert r.returncode == 0, r.stderr
    assert {"random", "n20", "failure"} <= {line.split()[0] for line in r.stdout.splitlines() if line.strip()}
    _short_mission(tmp_path, 20)
    r = plmarl("eval", str(tmp_path / "short.yaml"), "--methods", "pl-marl", "--tup", "50", "--episodes", "2",
               "--from-s", "5", "--json")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["policies"] == str(ROOT / "policies")
    r = plmarl("bench", "dt", "--envs", "1", "--json")  # the benches' default mission too
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["n_uavs"] == 4
