"""`python -m plmarl_sitl.bench.episodes`: per-episode failure diagnostics on the suite's own
episodes, in the real twin with the shipped policies (2 episodes of failure_2of6, T_up 50:
one per mission variant, two UAVs failing at 100 s)."""

from __future__ import annotations

import contextlib
import io
import json

import pytest

from plmarl_sitl.bench.episodes import apply_sets, main, parse_sets
from plmarl_sitl.cli import main as plmarl
from plmarl_sitl.config import PROJECT_SUITE
from plmarl_sitl.errors import UserError
from plmarl_sitl.learning.eval.suite import load_suite

FAMILY, SEED = "failure_2of6", 38
TINY = ["--tup", "50", "--episodes", "2", "--seed", str(SEED), "--json"]


def run_json(capsys: pytest.CaptureFixture[str], *args: str) -> dict:
    assert main([FAMILY, *args, *TINY]) == 0
    return json.loads(capsys.readouterr().out)


def per_episode(doc: dict, method: str, key: str) -> list:
    (row,) = [r for r in doc["rows"] if r["method"] == method]
    return row["per_episode"][key]


@pytest.fixture(scope="module")
def bench(tmp_path_factory: pytest.TempPathFactory) -> dict:
    out = tmp_path_factory.mktemp("episodes")
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):  # a module fixture has no capsys
        rc = main([FAMILY, "--methods", "pl-marl,service,service-resolve", "--out", str(out), *TINY])
    assert rc == 0
    doc = json.loads(stdout.getvalue())  # exactly one JSON object
    assert json.loads((out / "results.json").read_text()) == doc
    assert "| failure_2of6 | 50 | service |" in (out / "results.md").read_text()
    return doc


def test_coverage_is_the_suites_per_episode_coverage(bench: dict, capsys: pytest.CaptureFixture[str]) -> None:
    assert plmarl(["suite", FAMILY, "--methods", "pl-marl,service", "--tup", "50", "--episodes", "2",
                   "--seed", str(SEED), "--json"]) == 0
    suite = json.loads(capsys.readouterr().out)
    for method in ("pl-marl", "service"):
        (row,) = [r for r in suite["rows"] if r["method"] == method]
        assert per_episode(bench, method, "coverage") == row["coverage_per_episode"]  # exactly: same episodes, same ops
        (tr,) = [t for t in suite["transients"] if t["method"] == method]
        assert per_episode(bench, method, "after_failure30") == tr["after_target_per_episode"]
    assert bench["families"][0]["twin_seeds"] == suite["families"][0]["twin_seeds"]


def test_the_failed_uavs_are_declared(bench: dict) -> None:
    for method in ("pl-marl", "service"):
        dead = per_episode(bench, method, "dead")
        declared = per_episode(bench, method, "dead_declared")
        assert dead == [2, 2]  # failure_2of6: two of six fail at 100 s in every episode
        assert max(declared) >= 1 and all(d <= n for d, n in zip(declared, dead, strict=True))
        assert all(u <= n for u, n in zip(per_episode(bench, method, "undeclared_end"), dead, strict=True))
        delays = [d for d in per_episode(bench, method, "detect_s") if d is not None]
        assert delays and all(0 <= d <= 60 for d in delays)  # declared after the failure, within a T_up and a bit
        assert all(0 <= s <= 1 for s in per_episode(bench, method, "split_share"))
    assert [c["method"] for c in bench["comparisons"]] == ["service", "service-resolve"]
    assert all(c["versus"] == "pl-marl" and "p_paired" in c["coverage"] for c in bench["comparisons"])
    assert bench["commit"] and bench["seed"] == SEED and "bench.episodes" in bench["command"]


def test_set_failure_replan_changes_the_missions_and_the_run(bench: dict, capsys: pytest.CaptureFixture[str]) -> None:
    _, families = load_suite(PROJECT_SUITE)
    sets = parse_sets(["failure_replan=resolve"])
    assert {m.failure_replan for m in families[FAMILY].missions} == {"local"}
    assert {apply_sets(m, sets).failure_replan for m in families[FAMILY].missions} == {"resolve"}
    doc = run_json(capsys, "--methods", "service", "--set", "failure_replan=resolve")
    assert doc["set"] == {"failure_replan": "resolve"}
    # The plan follower re-solving whole is the suite's service-resolve, episode for episode,
    # and not the default's local repairs.
    assert per_episode(doc, "service", "coverage") == per_episode(bench, "service-resolve", "coverage")
    assert per_episode(doc, "service", "coverage") != per_episode(bench, "service", "coverage")


@pytest.mark.parametrize("item, says", [("bogus=1", "unknown key 'bogus'"), ("failure_replan=later", "bad value 'later'"),
                                        ("failure_replan", "give key=value")])
def test_a_bad_set_is_one_line_and_exit_2(item: str, says: str, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(UserError, match=says):
        parse_sets([item])
    assert main([FAMILY, "--set", item, *TINY]) == 2
    cap = capsys.readouterr()
    err = cap.err.strip()
    assert cap.out == "" and err.count("\n") == 0 and says in err and "failure_replan" in err
