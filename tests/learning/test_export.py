"""TorchScript round trip == eager, and clear errors for missing/corrupt/mismatched files."""

from __future__ import annotations

import dataclasses
import shutil
import warnings
from pathlib import Path

import pytest
import torch

from plmarl_sitl.errors import PolicyFileError, UserError
from plmarl_sitl.learning.nn import Actor, BeliefTracker, DeployedPolicy, FeatureScales, make_predictor
from plmarl_sitl.learning.nn.io import export_policy, load_policy
from plmarl_sitl.mission import load_mission
from plmarl_sitl.model.coverage import SENSING_FEATURES

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def mission():
    return load_mission(ROOT / "missions" / "paper_urban.yaml")


def _export(tmp: Path, mission, kind: str = "mlp") -> tuple[BeliefTracker, DeployedPolicy]:
    torch.manual_seed(0)
    pred = make_predictor(kind)
    for p in pred.parameters():  # non-trivial weights (the MLP's output layer starts at zero)
        torch.nn.init.normal_(p, std=0.3)
    tracker = BeliefTracker(pred, 10, 1.0)
    policy = DeployedPolicy(Actor(), *FeatureScales.from_mission(mission))
    export_policy(tmp, tracker, policy, {"method": "test", "seed": 0})
    return tracker, policy


@pytest.mark.parametrize("kind", ["mlp", "gru"])
def test_round_trip_equals_eager(tmp_path: Path, mission, kind: str) -> None:
    tracker, policy = _export(tmp_path, mission, kind)
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)  # loading must not warn at users
        loaded = load_policy(tmp_path, mission)
    gen = torch.Generator().manual_seed(1)
    held = torch.randn(3, 6, generator=gen) * 20
    t_rx = torch.tensor([0.0, 0.0, -1e9])
    b1, s1 = tracker.init_state(held)
    b2, s2 = loaded.tracker.init_state(held)
    for t in range(6):
        e1, a1, b1, s1 = tracker(float(t), held, t_rx, b1, s1)
        e2, a2, b2, s2 = loaded.tracker(float(t), held, t_rx, b2, s2)
        assert torch.allclose(e1, e2, atol=1e-6) and torch.equal(a1, a2)
    ego = torch.tensor([300.0, 400.0, -90.0, 1.0, 2.0, 0.0])
    mask = torch.tensor([True, True, False])
    sense = torch.rand(SENSING_FEATURES, generator=gen)
    demand = torch.tensor([[250.0, 350.0, 40.0], [550.0, 450.0, 7.0], [950.0, 50.0, 60.0]])
    for fail in (False, True):
        for d in (demand, None):
            want = policy(ego, e1, mask, sense, torch.tensor(fail), d)
            got = loaded.policy(ego, e2, mask, sense, torch.tensor(fail), d)
            assert torch.allclose(want, got, atol=1e-6)


def test_missing_file_is_named(tmp_path: Path, mission) -> None:
    _export(tmp_path, mission)
    (tmp_path / "policy.pt").unlink()
    with pytest.raises(PolicyFileError, match=r"policy\.pt: missing"):
        load_policy(tmp_path)
    with pytest.raises(PolicyFileError, match="missing policy directory"):
        load_policy(tmp_path / "nope")


def test_corrupt_files_are_named(tmp_path: Path, mission) -> None:
    _export(tmp_path, mission)
    (tmp_path / "predictor.pt").write_bytes(b"not a zip file")
    with pytest.raises(PolicyFileError, match=r"predictor\.pt: does not match card\.yaml"):
        load_policy(tmp_path)
    # Junk with a matching hash in the card is reported as corrupt.
    card = (tmp_path / "card.yaml").read_text()
    import yaml

    c = yaml.safe_load(card)
    from plmarl_sitl.learning.nn.io import sha256

    c["sha256"]["predictor.pt"] = sha256(tmp_path / "predictor.pt")
    (tmp_path / "card.yaml").write_text(yaml.safe_dump(c))
    with pytest.raises(PolicyFileError, match=r"predictor\.pt: corrupt: not a loadable TorchScript"):
        load_policy(tmp_path)
    (tmp_path / "card.yaml").write_text("method: [unclosed")
    with pytest.raises(PolicyFileError, match=r"card\.yaml: corrupt: not valid YAML"):
        load_policy(tmp_path)


def test_mismatched_files_are_named(tmp_path: Path, mission) -> None:
    a, b = tmp_path / "a", tmp_path / "b"
    _export(a, mission)
    other = dataclasses.replace(mission, radii=dataclasses.replace(mission.radii, comm_m=500.0))
    torch.manual_seed(0)
    export_policy(b, BeliefTracker(make_predictor("cv"), 10, 1.0), DeployedPolicy(Actor(), *FeatureScales.from_mission(other)), {"method": "x"})
    shutil.copy(b / "policy.pt", a / "policy.pt")  # the policy of another export
    with pytest.raises(PolicyFileError, match=r"policy\.pt: does not match card\.yaml"):
        load_policy(a)
    with pytest.raises(PolicyFileError, match=r"policy\.pt: mismatched with mission 'paper_urban': r_comm"):
        load_policy(b, mission)
    assert issubclass(PolicyFileError, UserError)  # the CLI prints it as one line, exit 2


def test_a_mission_with_other_cluster_sizes_flies_the_policy(tmp_path: Path, mission) -> None:
    """demand_unit is the policy's own unit of the map's counts, not a property of the vehicle:
    a mission with clusters of 40 loads a policy trained on clusters of 60 (and it keeps 60)."""
    _export(tmp_path, mission)
    users = dataclasses.replace(mission.users, count=160, cluster_size=40)
    lp = load_policy(tmp_path, dataclasses.replace(mission, users=users))
    assert float(lp.policy.demand_unit) == float(mission.users.cluster_size)


def test_agent_with_no_neighbour_slots(tmp_path: Path, mission) -> None:
    """M = 0 (an isolated agent): both files run and the policy still acts."""
    _export(tmp_path, mission)
    lp = load_policy(tmp_path, mission)
    held = torch.zeros(0, 6)
    buf, seen = lp.tracker.init_state(held)
    belief, aoi, buf, seen = lp.tracker(3.0, held, torch.zeros(0), buf, seen)
    assert belief.shape == (0, 6) and aoi.shape == (0,)
    accel = lp.policy(torch.tensor([300.0, 400.0, -90.0, 0.0, 0.0, 0.0]), belief, torch.zeros(0, dtype=torch.bool),
                      torch.zeros(SENSING_FEATURES), torch.tensor(False))
    assert accel.shape == (3,) and torch.isfinite(accel).all()
