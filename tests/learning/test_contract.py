"""The typed policy contract (learning/nn/contract.py): PolicyInputs scripts, every shipped
policy keeps its outputs through the one adapter, and the twin's perception step gives each
input version what it was trained with."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import pytest
import torch

from plmarl_sitl.config import PAPER_MISSION
from plmarl_sitl.learning.nn import Actor, BeliefTracker, DeployedPolicy, FeatureScales, make_predictor
from plmarl_sitl.learning.nn.contract import PolicyCall, PolicyForm, PolicyInputs
from plmarl_sitl.learning.nn.features import build_policy_input, ring_edges_sq
from plmarl_sitl.learning.nn.io import load_policy, quiet_torchscript, script, sha256
from plmarl_sitl.learning.nn.perception import Perception
from plmarl_sitl.mission import load_mission
from plmarl_sitl.twin.env import CoverageEnv

ROOT = Path(__file__).resolve().parents[2]
SHIPPED = ["pl-marl", "gru", "tag-mappo", "transit/pl-marl", "transit/gru", "transit/tag-mappo", "plan/pl-marl", "plan/gru", "plan/tag-mappo", "wave1/pl-marl", "wave1/gru", "wave1/tag-mappo"]
# Outputs of the shipped files on fixed inputs, recorded at commit cde96d6 (before the
# contract, on an Intel Xeon) with each file's positional call written out per input version; the
# session-20 defaults and the session-21 transit/ files (trained after the contract) through the adapter,
# on an AMD EPYC.
GOLDEN = json.loads((Path(__file__).parent / "data" / "shipped_policy_outputs.json").read_text())
MISSION = load_mission(PAPER_MISSION)


def _tensor(d: dict | None) -> torch.Tensor | None:
    if d is None:
        return None
    return torch.tensor(d["values"], dtype=getattr(torch, d["dtype"])).reshape(d["shape"])


CASES = [PolicyInputs(**{k: _tensor(v) for k, v in c.items()}) for c in GOLDEN["inputs"]]


@pytest.mark.parametrize("name", SHIPPED)
def test_every_shipped_policy_gives_its_recorded_outputs_through_the_adapter(name: str) -> None:
    lp = load_policy(ROOT / "policies" / name)  # sha256 checked against the card
    golden = GOLDEN["outputs"][name]
    if sha256(ROOT / "policies" / name / "policy.pt") != golden["policy_sha256"]:
        pytest.skip(f"policies/{name}/policy.pt is not the file the outputs were recorded from")
    with torch.no_grad():
        for x, want in zip(CASES, golden["accel"], strict=True):
            # To float32's last bits: the golden outputs were recorded on an Intel Xeon, and on an AMD EPYC
            # torch's CPU kernels round the same products differently (up to 1.2e-6 m/s^2). A wrong input
            # through the adapter moves an acceleration by far more than that.
            assert lp.call(x).flatten().tolist() == pytest.approx(want, rel=1e-5, abs=1e-5)


@pytest.mark.parametrize("name", SHIPPED)
def test_the_adapter_passes_each_file_the_inputs_of_its_version(name: str) -> None:
    """The adapter's call is the file's positional call written out for its card's version."""
    lp = load_policy(ROOT / "policies" / name)
    io = lp.card["io"]
    assert lp.form == PolicyForm(io.get("input_version", 1), bool(io.get("takes_plan", False)),
                                 bool(io.get("reads_map", io.get("input_version", 1) >= 2)))
    with torch.no_grad():
        for x in CASES:
            if lp.form.input_version == 1:
                want = lp.policy(x.ego, x.beliefs, x.mask, x.sense, x.fail)
            else:
                want = lp.policy(x.ego, x.beliefs, x.mask, x.sense, x.fail, x.demand, x.target)
            assert torch.equal(lp.call(x), want)
        if lp.form.takes_plan:  # the target reaches the file: another target, another action
            x = CASES[1]
            assert not torch.equal(lp.call(x), lp.call(x._replace(target=x.target + 200.0)))


class _SixInputs(torch.nn.Module):
    """A version-2 file of before the team plan (no `takes_plan`): six inputs."""

    def __init__(self, inner: DeployedPolicy) -> None:
        super().__init__()
        self.inner = inner
        self.input_version = 2

    def forward(self, ego: torch.Tensor, beliefs: torch.Tensor, mask: torch.Tensor, sense: torch.Tensor,
                fail_flag: torch.Tensor, demand: Optional[torch.Tensor] = None) -> torch.Tensor:  # noqa: UP045
        return self.inner(ego, beliefs, mask, sense, fail_flag, demand, None)


def test_a_six_input_file_gets_six_inputs() -> None:
    torch.manual_seed(0)
    inner = DeployedPolicy(Actor(), *FeatureScales.from_mission(MISSION))
    call = PolicyCall(script(_SixInputs(inner)))
    assert call.form == PolicyForm(2, False, True) and call.arity == 6
    with torch.no_grad():
        for x in CASES:
            assert torch.equal(call(x), inner(*x[:6]))  # the target never reaches it


class _TypedPolicy(torch.nn.Module):
    """A forward that takes PolicyInputs itself (what a typed file format would be)."""

    def __init__(self, inner: DeployedPolicy) -> None:
        super().__init__()
        self.inner = inner

    def forward(self, x: PolicyInputs) -> torch.Tensor:
        return self.inner(x.ego, x.beliefs, x.mask, x.sense, x.fail, x.demand, x.target)


def test_policy_inputs_script_save_and_load(tmp_path: Path) -> None:
    """PolicyInputs is TorchScript-safe: the feature step takes it inside every exported
    policy, and a module whose forward takes it saves, loads and gives the positional result."""
    torch.manual_seed(1)
    inner = DeployedPolicy(Actor(reads_map=True), *FeatureScales.from_mission(MISSION)).eval()
    with quiet_torchscript():
        torch.jit.save(torch.jit.script(_TypedPolicy(inner)), str(tmp_path / "typed.pt"))
        typed = torch.jit.load(str(tmp_path / "typed.pt"))
        features = torch.jit.script(build_policy_input)
    s = FeatureScales.from_mission(MISSION)
    with torch.no_grad():
        for x in CASES:
            assert torch.equal(typed(x), inner(*x))
            want = build_policy_input(x, s.alt_max, s.v_max, s.r_comm, s.claim_m, s.demand_unit, ring_edges_sq())
            got = features(x, s.alt_max, s.v_max, s.r_comm, s.claim_m, s.demand_unit, ring_edges_sq())
            assert all(torch.equal(a, b) for a, b in zip(want, got, strict=True))


def test_perception_gives_each_version_its_inputs() -> None:
    """Version 1: the raw flag, no map, no plan. The trained form: f by the predicted-in-range
    rule, the environment's map per agent, the plan's point."""
    tracker = BeliefTracker(make_predictor("hold"), MISSION.signalling.buffer_len, MISSION.timing.dt_s)
    m = MISSION.with_tup(5)
    env = CoverageEnv(m, 2, 5, failure_prob=1.0, failure_at_s=6.0)
    old = Perception(tracker, PolicyForm(1, False, False), MISSION.radii.comm_m)
    new = Perception(tracker, PolicyForm.trained(reads_map=False), MISSION.radii.comm_m, m)
    obs = env.reset()
    for _ in range(15):
        a, b = old(obs), new(obs)
        assert a.demand is None and a.target is None and torch.equal(a.fail, obs.fail_flag)
        assert torch.equal(a.ego, b.ego) and torch.equal(a.beliefs, b.beliefs) and torch.equal(a.mask, b.mask)
        assert b.demand.shape == (2, env.n) + obs.demand.shape[1:] and torch.equal(b.demand[:, 1], obs.demand)
        assert b.target.shape == (2, env.n, 2) and torch.equal(b.fail, new.flags.flag & obs.alive)
        obs, _, _ = env.step(torch.zeros(2, env.n, 3))
    assert bool(obs.fail_flag.any())  # the failure happened: the raw flag was exercised


def test_the_trained_form_is_the_exported_form() -> None:
    """What the trainer perceives for (PolicyForm.trained) is what the exported file takes."""
    for reads_map in (False, True):
        policy = DeployedPolicy(Actor(reads_map=reads_map), *FeatureScales.from_mission(MISSION))
        assert PolicyForm.of(policy) == PolicyForm.of(script(policy)) == PolicyForm.trained(reads_map)
