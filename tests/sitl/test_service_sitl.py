"""`plmarl swarm up MISSION --policy service`: the plan follower flies in lockstep SITL (the
project's policies/service/, found by name) and its coverage is the twin's `service`, second
by second."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from plmarl_sitl.learning.eval.controllers import ServiceController
from plmarl_sitl.mission import load_mission
from plmarl_sitl.twin.env import CoverageEnv

pytestmark = [pytest.mark.integration, pytest.mark.slow]  # a whole SITL swarm, ~40 s
ROOT = Path(__file__).resolve().parents[2]


def _twin_service_trace(mission_path: Path, seed: int) -> list[float]:
    mission = load_mission(mission_path)
    env = CoverageEnv(mission, 1, seed)
    ctl = ServiceController(mission)
    ctl.reset()
    obs = env.observe()
    trace = []
    while not env.done:
        obs, _, info = env.step(ctl.act(obs))
        trace.append(info.coverage[0])
    return torch.cat(trace).tolist()


def test_service_flies_in_lockstep_sitl_as_in_the_twin(tmp_path: Path) -> None:
    mission = tmp_path / "short.yaml"
    mission.write_text(f"extends: {ROOT / 'missions' / 'paper_urban.yaml'}\nname: short_service\ntiming: {{episode_s: 20}}\n")
    out = tmp_path / "run"
    r = subprocess.run([sys.executable, "-m", "plmarl_sitl.cli", "swarm", "up", str(mission), "--policy", "service",
                        "--lockstep", "--speedup", "10", "--headless", "--json", "--seed", "3", "--out", str(out)],
                       capture_output=True, text=True, timeout=280, cwd=tmp_path)  # not the checkout: found by name
    assert r.returncode == 0, r.stderr[-2000:]
    rows = {row["t"]: row["coverage"] for row in map(json.loads, (out / "metrics.jsonl").read_text().splitlines())}
    sitl = [rows[t] for t in range(1, 21)]
    twin = _twin_service_trace(mission, 3)
    assert sum(twin) / 20 > 0.5  # it flew out to the clusters
    assert max(abs(a - b) for a, b in zip(sitl, twin, strict=True)) <= 0.01
