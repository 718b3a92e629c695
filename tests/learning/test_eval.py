"""Statistics against scipy, and `plmarl eval --json` end to end on tiny exported policies."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy import stats

from plmarl_sitl.cli import main
from plmarl_sitl.cli.eval import _tups
from plmarl_sitl.learning.eval.stats import compare, mann_whitney_p, mean_ci95, paired_wilcoxon_p
from plmarl_sitl.learning.nn import Actor, BeliefTracker, DeployedPolicy, FeatureScales, make_predictor
from plmarl_sitl.learning.nn.io import export_policy
from plmarl_sitl.mission import load_mission

ROOT = Path(__file__).resolve().parents[2]


def test_mean_ci95_matches_scipy_t_interval() -> None:
    x = np.random.default_rng(0).normal(0.8, 0.05, size=37)
    mean, (lo, hi) = mean_ci95(x)
    want = stats.t.interval(0.95, len(x) - 1, loc=x.mean(), scale=stats.sem(x))
    assert mean == pytest.approx(x.mean())
    assert (lo, hi) == pytest.approx(want)


def test_mann_whitney_matches_scipy() -> None:
    rng = np.random.default_rng(1)
    a, b = rng.normal(0.8, 0.05, 100), rng.normal(0.78, 0.05, 100)
    assert mann_whitney_p(a, b) == pytest.approx(stats.mannwhitneyu(a, b, alternative="two-sided").pvalue)
    assert mann_whitney_p(a, a + 1.0) < 1e-10


def test_paired_wilcoxon_sees_a_small_shift_that_mann_whitney_misses_across_spread_episodes() -> None:
    """The suite's design: every method flies the same episodes, and episodes differ far more than methods."""
    rng = np.random.default_rng(2)
    base = rng.uniform(0.3, 0.9, 30)  # episodes of several missions: a wide spread
    better = base + 0.01 + rng.normal(0, 0.003, 30)
    assert paired_wilcoxon_p(better, base) == pytest.approx(stats.wilcoxon(better - base).pvalue)
    assert paired_wilcoxon_p(better, base) < 1e-5
    assert mann_whitney_p(better, base) > 0.5
    c = compare(better, base)
    assert c["wins"] + c["losses"] <= 30 and c["wins"] > 25 and c["p"] == mann_whitney_p(better, base)
    # Identical episodes: no evidence either way; ties count as neither a win nor a loss.
    assert compare(base, base) == {"p": 1.0, "p_paired": 1.0, "wins": 0, "losses": 0}
    with pytest.raises(ValueError, match="differ in length"):
        paired_wilcoxon_p(base, base[:-1])


def test_tup_ranges() -> None:
    assert _tups("5,10,...,50") == [5, 10, 15, 20, 25, 30, 35, 40, 45, 50]
    assert _tups("5,15,50") == [5, 15, 50]


def test_eval_json_end_to_end(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    mission = load_mission(ROOT / "missions" / "paper_urban.yaml")
    scales = FeatureScales.from_mission(mission)
    torch.manual_seed(0)
    for method, kind in (("pl-marl", "mlp"), ("tag-mappo", "hold")):
        export_policy(tmp_path / method, BeliefTracker(make_predictor(kind), 10, 1.0), DeployedPolicy(Actor(), *scales),
                      {"method": method, "seed": 0})
    rc = main([
        "eval", str(ROOT / "missions" / "paper_urban.yaml"), "--methods", "pl-marl,tag-mappo,dead-reckoning",
        "--tup", "5,50", "--episodes", "3", "--seed", "2", "--policies", str(tmp_path), "--json",
        "--out", str(tmp_path / "out"),
    ])
    assert rc == 0
    doc = json.loads(capsys.readouterr().out)
    assert set(doc) == {"results", "p_values", "policies"}
    assert len(doc["results"]) == 6 and len(doc["p_values"]) == 4
    for r in doc["results"]:
        assert set(r) == {"method", "tup", "coverage_mean", "coverage_ci95", "lambda2_mean"}
        assert r["coverage_ci95"][0] <= r["coverage_mean"] <= r["coverage_ci95"][1]
    for p in doc["p_values"]:
        assert set(p) == {"method", "versus", "tup", "p", "p_paired", "wins", "losses"} and p["method"] == "pl-marl"
        assert 0 <= p["p"] <= 1 and 0 <= p["p_paired"] <= 1 and p["wins"] + p["losses"] <= 3
    assert (tmp_path / "out" / "coverage_vs_tup.png").stat().st_size > 1000
    md = (tmp_path / "out" / "results.md").read_text()
    assert "| T_up (s) |" in md and "paired Wilcoxon signed-rank p" in md


def test_eval_missing_policy_is_one_line_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["eval", str(ROOT / "missions" / "paper_urban.yaml"), "--methods", "gru", "--tup", "5",
               "--episodes", "2", "--policies", str(tmp_path)])
    assert rc == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "gru" in err and "missing" in err


def test_coinciding_lines_are_named_and_failures_told_apart(tmp_path) -> None:
    """Issue 26: identical curves hid all methods but one; results.md said "failure
    probability 0.0" when the mission's scripted failure fired."""
    import numpy as np

    from plmarl_sitl.learning.eval.report import coinciding, failures_text, plot_coverage_vs_tup
    from plmarl_sitl.mission import load_mission

    ys = {"pl-marl": np.array([0.95, 0.94]), "gru": np.array([0.9505, 0.9401]), "greedy": np.array([0.96, 0.96])}
    assert coinciding(ys) == [["pl-marl", "gru"], ["greedy"]]
    rows = [{"method": m, "tup": t, "coverage_mean": float(y[i]), "coverage_ci95": [0.9, 0.99]}
            for m, y in ys.items() for i, t in enumerate((5, 50))]
    plot_coverage_vs_tup({"results": rows, "extra": {"rows": [], "from_s": 50, "episodes": 3}}, tmp_path / "c.png")
    assert (tmp_path / "c.png").stat().st_size > 10_000
    root = Path(__file__).resolve().parents[2]
    assert failures_text(load_mission(root / "missions/node_failure.yaml"), 0.0) == \
        "scripted node failures: UAV 2 at t = 100 s; no random failure"
    assert "random node failure at t = 100 s with probability 0.2" in failures_text(load_mission(root / "missions/paper_urban.yaml"), 0.2)
