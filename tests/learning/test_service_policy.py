"""`service` is a documented method: in every command's --help, runnable from the CLI in the
twin, and a policy file (policies/service/) that flies exactly the twin's plan follower."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import torch

from plmarl_sitl.learning.eval.controllers import LearnedController, ServiceController
from plmarl_sitl.learning.nn.io import load_policy
from plmarl_sitl.learning.nn.service_policy import export_service_policy, service_policy
from plmarl_sitl.mission import load_mission
from plmarl_sitl.twin.rollout import rollout

ROOT = Path(__file__).resolve().parents[2]
PAPER = ROOT / "missions" / "paper_urban.yaml"


def plmarl(*args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "plmarl_sitl.cli", *args], capture_output=True, text=True,
                          timeout=280, cwd=cwd)


def test_every_method_list_documents_service_and_the_references() -> None:
    for cmd in (["eval", "--help"], ["suite", "--help"], ["sim", "--help"]):
        r = plmarl(*cmd)
        assert r.returncode == 0, r.stderr
        text = " ".join(r.stdout.split())
        for m in ("service", "greedy", "clairvoyant"):
            assert m in text, (cmd, m)
        assert "plan follower" in text and "proven bound" in text  # what service is, and that no reference is a bound
        assert "Oracle" not in text  # the greedy is no longer called a bound
    from plmarl_sitl.cli.eval import DEFAULT_METHODS as EVAL_DEFAULT
    from plmarl_sitl.cli.suite import DEFAULT_METHODS as SUITE_DEFAULT

    for default in (EVAL_DEFAULT, SUITE_DEFAULT):  # the default methods run service and the references
        assert {"service", "greedy", "clairvoyant", "pl-marl"} <= set(default.split(","))


def test_service_and_the_greedy_run_from_the_cli_and_oracle_is_a_deprecated_alias(tmp_path: Path) -> None:
    (tmp_path / "short.yaml").write_text(f"extends: {PAPER}\nname: short\ntiming: {{episode_s: 30}}\n")
    r = plmarl("sim", str(tmp_path / "short.yaml"), "--method", "service", "--episodes", "2", "--seed", "4", "--json")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert doc["method"] == "service" and 0.0 < doc["coverage_mean"] <= 1.0
    r = plmarl("sim", str(tmp_path / "short.yaml"), "--method", "oracle", "--episodes", "1", "--json")
    assert r.returncode == 0 and json.loads(r.stdout)["method"] == "greedy"
    assert r.stderr.strip().count("\n") == 0 and "'oracle' is now 'greedy'" in r.stderr
    r = plmarl("eval", str(tmp_path / "short.yaml"), "--methods", "service,oracle", "--tup", "15", "--episodes", "2",
               "--from-s", "5", "--json")
    assert r.returncode == 0, r.stderr
    rows = json.loads(r.stdout)["results"]
    assert [x["method"] for x in rows] == ["service", "greedy"]
    r = plmarl("sim", str(PAPER), "--method", "nosuch")
    assert r.returncode == 2 and "service" in r.stderr


def test_the_policy_file_flies_the_twins_plan_follower(tmp_path: Path) -> None:
    mission = load_mission(PAPER).with_tup(15)
    lp = load_policy(export_service_policy(mission, tmp_path / "service"), mission)
    assert lp.card["learnt"] is False and "NOT LEARNT" in lp.card["note"] and lp.takes_plan
    ref = rollout(mission, lambda env: ServiceController(env.mission), 3, 7, batch=3)
    pol = rollout(mission, lambda env: LearnedController(lp.tracker, lp.policy, env.mission), 3, 7, batch=3)
    np.testing.assert_allclose(pol[0].coverage.numpy(), ref[0].coverage.numpy(), atol=1e-6)
    assert float(ref[0].coverage[:, 50:].mean()) > 0.9


def test_the_shipped_service_policy_is_the_export_of_the_paper_mission() -> None:
    mission = load_mission(PAPER)
    shipped = load_policy(ROOT / "policies" / "service", mission)
    fresh = service_policy(mission)
    g = torch.Generator().manual_seed(0)
    ego = torch.randn(5, 6, generator=g) * 100
    target = torch.rand(5, 2, generator=g) * 1000
    args = (ego, torch.zeros(5, 3, 6), torch.ones(5, 3, dtype=torch.bool), torch.zeros(5, 4), torch.zeros(5, dtype=torch.bool),
            torch.zeros(5, 1, 3))
    torch.testing.assert_close(shipped.policy(*args, target), fresh(*args, target))
    assert shipped.card["cruise_alt_m"] == fresh.cruise_alt


def test_the_local_repairs_methods_are_aliases_of_the_default_since_it_repairs(capsys) -> None:  # noqa: ANN001
    """Session 27 made local repairs the default: `*-local-repairs` name the default for one
    release (a one-line note), `*-resolve` fly the old default."""
    from plmarl_sitl.learning.eval.methods import METHOD_HELP, parse_methods

    assert parse_methods("pl-marl-local-repairs,service-local-repairs,pl-marl-resolve") == ["pl-marl", "service", "pl-marl-resolve"]
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and "'pl-marl-local-repairs' is now 'pl-marl'" in err[0] and "pl-marl-resolve" in err[0]
    assert {"pl-marl-resolve", "service-resolve"} <= set(METHOD_HELP) and "pl-marl-local-repairs" not in METHOD_HELP
