"""A policy preloaded by the agents' forkserver (deploy/agent/preload.py) is used only for
exactly the files it was loaded from."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import torch

from plmarl_sitl.deploy.agent.preload import preload, preloaded, preloaded_mission
from plmarl_sitl.learning.nn.io import load_policy
from plmarl_sitl.mission import load_mission

ROOT = Path(__file__).resolve().parents[2]


def test_a_preloaded_policy_is_found_only_for_the_same_unchanged_files(tmp_path: Path) -> None:
    policy = tmp_path / "pl-marl"
    shutil.copytree(ROOT / "policies" / "pl-marl", policy)
    mission = tmp_path / "mission.yaml"
    shutil.copy(ROOT / "missions" / "paper_urban.yaml", mission)
    other = tmp_path / "other.yaml"
    shutil.copy(ROOT / "missions" / "paper_urban.yaml", other)
    assert preloaded(policy, mission) is None
    preload(policy, mission)
    lp = preloaded(policy, mission)
    assert lp is not None and preloaded(str(policy) + "/", str(mission)) is lp  # the same files, spelt differently
    assert preloaded(policy, other) is None
    ref = load_policy(policy, load_mission(mission))
    held = torch.rand(4, 6) * 100.0
    outs = []
    for a in (lp, ref):
        buf, seen = a.tracker.init_state(held)
        outs.append(a.tracker(1.0, held, torch.zeros(4), buf, seen)[0])
    assert torch.equal(outs[0], outs[1])
    st = mission.stat()
    os.utime(mission, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000))  # the mission file changed since
    assert preloaded(policy, mission) is None
    assert preloaded(tmp_path / "gone", mission) is None


def test_a_preloaded_mission_is_found_only_for_the_same_unchanged_file(tmp_path: Path) -> None:
    mission = tmp_path / "mission.yaml"
    shutil.copy(ROOT / "missions" / "paper_urban.yaml", mission)
    other = tmp_path / "other.yaml"
    shutil.copy(ROOT / "missions" / "paper_urban.yaml", other)
    assert preloaded_mission(mission) is None
    preload(ROOT / "policies" / "pl-marl", mission)
    m = preloaded_mission(str(mission))
    assert m is not None and m == load_mission(mission)
    assert preloaded_mission(other) is None
    st = mission.stat()
    os.utime(mission, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000))  # the mission file changed since
    assert preloaded_mission(mission) is None
    assert preloaded_mission(tmp_path / "gone.yaml") is None


def test_the_forkserver_holds_no_training_module() -> None:
    """Every module the forkserver imports is in every forked agent's RSS (issue 24.2): the agent
    only loads TorchScript files, so the training and export modules stay out of it."""
    import subprocess
    import sys

    code = ("import sys, plmarl_sitl.sitl.forked_child; "
            "print(' '.join(m for m in sys.modules if m.startswith('plmarl_sitl.learning')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT).stdout.split()
    assert "plmarl_sitl.learning.nn.io" in out
    for training in ("belief", "policy", "predictor", "fused"):
        assert f"plmarl_sitl.learning.nn.{training}" not in out
    from plmarl_sitl.learning import nn

    assert nn.Actor.__module__ == "plmarl_sitl.learning.nn.policy"  # the package's names still resolve, on first use
    try:
        nn.NoSuchName  # noqa: B018
    except AttributeError:
        pass
    else:
        raise AssertionError("an unknown name resolved")
