"""The fused tracker and policy (plmarl_sitl/learning/nn/fused.py) compute what the reference modules compute."""

from __future__ import annotations

import pytest
import torch

from plmarl_sitl.learning.nn import Actor, BeliefTracker, DeployedPolicy, make_predictor
from plmarl_sitl.learning.nn.belief import NEVER
from plmarl_sitl.learning.nn.convert import fuse_directory
from plmarl_sitl.learning.nn.fused import fuse_policy, fuse_tracker, fused_policy_from_file, is_fused
from plmarl_sitl.learning.nn.io import POLICY_ATTRS, TRACKER_ATTRS, freeze, load_policy


def _tracker(seed: int = 0) -> BeliefTracker:
    torch.manual_seed(seed)
    pred = make_predictor("mlp")
    for p in pred.parameters():  # non-trivial weights (the output layer starts at zero)
        torch.nn.init.normal_(p, std=0.3)
    return BeliefTracker(pred, 10, 1.0).eval()


def _scenario(m: int, gen: torch.Generator) -> list[tuple[float, torch.Tensor, torch.Tensor]]:
    """Seconds 0..11 of held states / reception times with every case the tracker knows:
    updates, predictions, a first reception mid-way, a slot never heard (an agent's own
    slot), and a reception time ahead of t (the twin's catch-up)."""
    out = []
    held = torch.cat([torch.rand(m, 3, generator=gen) * torch.tensor([1000.0, 1000.0, -120.0]), torch.randn(m, 3, generator=gen) * 5], -1)
    t_rx = torch.full((m,), NEVER)
    for t in range(12):
        held = held.clone()
        if t % 5 == 0:  # an update for the first half of the slots
            k = max(1, m // 2)
            held[:k] = held[:k] + torch.randn(k, 6, generator=gen)
            t_rx = t_rx.clone()
            t_rx[:k] = float(t)
        if t == 7 and m > 2:  # first reception of slot m-2, stamped one second ahead of t
            t_rx = t_rx.clone()
            t_rx[m - 2] = 8.0
        out.append((float(t), held, t_rx))
    return out  # slot m-1 is never heard


@pytest.mark.parametrize("m", [1, 3, 19])
def test_fused_tracker_is_bit_identical_on_one_agent(m: int) -> None:
    ref = _tracker()
    fused = freeze(fuse_tracker(ref), TRACKER_ATTRS)
    assert is_fused(fused)
    gen = torch.Generator().manual_seed(m)
    steps = _scenario(m, gen)
    with torch.no_grad():
        b1, s1 = ref.init_state(steps[0][1])
        b2, s2 = fused.init_state(steps[0][1])
        for t, held, t_rx in steps:
            o1 = ref(t, held, t_rx, b1, s1)
            o2 = fused(t, held, t_rx, b2, s2)
            for a, b in zip(o1, o2, strict=True):
                assert torch.equal(a, b)
            _, _, b1, s1 = o1
            _, _, b2, s2 = o2


def test_fused_tracker_other_shapes_use_the_reference() -> None:
    ref = _tracker(1)
    fused = freeze(fuse_tracker(ref), TRACKER_ATTRS)
    gen = torch.Generator().manual_seed(3)
    for shape in [(0,), (2, 4), (2, 3, 3)]:
        held = torch.randn(*shape, 6, generator=gen) * 50
        t_rx = torch.where(torch.rand(shape, generator=gen) > 0.3, torch.zeros(shape), torch.full(shape, NEVER))
        with torch.no_grad():
            b1, s1 = ref.init_state(held)
            b2, s2 = fused.init_state(held)
            for t in range(4):
                o1 = ref(float(t), held, t_rx, b1, s1)
                o2 = fused(float(t), held, t_rx, b2, s2)
                assert all(torch.equal(a, b) for a, b in zip(o1, o2, strict=True))
                _, _, b1, s1 = o1
                _, _, b2, s2 = o2


def _policy(seed: int = 0, reads_map: bool = True) -> DeployedPolicy:
    torch.manual_seed(seed)
    actor = Actor(reads_map=reads_map)
    for prm in actor.parameters():  # non-trivial weights (mu starts near zero)
        torch.nn.init.normal_(prm, std=0.3)
    return DeployedPolicy(actor, 150.0, 20.0, 5.0, 350.0, 100.0, 60.0).eval()


def _one_agent_inputs(gen: torch.Generator, m: int, k: int, case: int) -> tuple:
    """One agent's raw inputs over a 1.5 km area; every 4th case puts the cells on a 50 m grid
    and the agent on a grid corner (offsets on the octant boundaries |dn| = |de| and dn = 0)."""
    ego = torch.cat([torch.rand(2, generator=gen) * 1500, -torch.rand(1, generator=gen) * 150, torch.randn(3, generator=gen) * 5])
    beliefs = torch.cat([torch.rand(m, 2, generator=gen) * 1500, -torch.rand(m, 1, generator=gen) * 150,
                         torch.randn(m, 3, generator=gen) * 5], 1)
    mask = torch.rand(m, generator=gen) < 0.7 if case % 3 else torch.ones(m, dtype=torch.bool)
    if case % 5 == 4:
        mask = torch.zeros(m, dtype=torch.bool)  # nobody heard: the attention gives m = 0
    demand = torch.cat([torch.rand(k, 2, generator=gen) * 1500, torch.randint(0, 40, (k, 1), generator=gen).float()], 1)
    if case % 4 == 0:
        demand[:, :2] = (demand[:, :2] / 50).floor() * 50 + 25
        ego[:2] = torch.tensor([525.0, 475.0])
    if case % 6 == 1:
        beliefs[0, :2] = demand[0, :2] + 30.0  # a neighbour claims a cell
    target = torch.rand(2, generator=gen) * 1500
    sense, fail = torch.rand(4, generator=gen), torch.tensor(case % 2 == 0)
    return ego, beliefs, mask, sense, fail, demand, target


@pytest.mark.parametrize("reads_map", [True, False], ids=["map", "map-blind"])
@pytest.mark.parametrize("source", ["eager", "file"])
def test_fused_policy_equals_the_reference_on_one_agent(source: str, reads_map: bool, tmp_path) -> None:  # noqa: ANN001
    from plmarl_sitl.learning.nn.io import quiet_torchscript

    ref = _policy(reads_map=reads_map)
    if source == "eager":
        fused = freeze(fuse_policy(ref), POLICY_ATTRS)
    else:  # an unfused frozen file, as exported before the fused form: weights read back from its graph
        with quiet_torchscript():
            torch.jit.save(freeze(ref, POLICY_ATTRS), str(tmp_path / "policy.pt"))
            fused = freeze(fused_policy_from_file(torch.jit.load(str(tmp_path / "policy.pt"))), POLICY_ATTRS)
    assert is_fused(fused) and fused.reads_map == reads_map
    gen = torch.Generator().manual_seed(7)
    worst = 0.0
    with torch.no_grad():
        for case in range(60):
            m, k = int(torch.randint(1, 21, (1,), generator=gen)), int(torch.randint(1, 100, (1,), generator=gen))
            args = _one_agent_inputs(gen, m, k, case)
            a, b = ref(*args), fused(*args)
            assert a.shape == b.shape == (3,)
            worst = max(worst, float((a - b).abs().max()))
    assert worst < 1e-4, worst  # float32 rounding of sums in another order (accelerations up to 5 m/s^2)


@pytest.mark.parametrize("reads_map", [True, False], ids=["map", "map-blind"])
def test_fused_policy_other_calls_use_the_reference(reads_map: bool) -> None:
    ref = _policy(1, reads_map)
    fused = freeze(fuse_policy(ref), POLICY_ATTRS)
    gen = torch.Generator().manual_seed(8)
    ego, beliefs, mask, sense, fail, demand, target = _one_agent_inputs(gen, 5, 12, 1)
    calls = [
        (ego, beliefs, mask, sense, fail, None, None),  # no map yet
        (ego, beliefs, mask, sense, fail, demand, None),  # a map, no plan yet
        (ego, beliefs[:0], mask[:0], sense, fail, demand, target),  # no neighbour slot
        (ego[None], beliefs[None], mask[None], sense[None], fail[None], demand[None], target[None]),  # a batch
    ]
    if reads_map:  # (a map-blind policy's fast path does not look at the map)
        calls.append((ego, beliefs, mask, sense, fail, demand[:0], target))  # an empty map
    with torch.no_grad():
        for args in calls:
            assert torch.equal(ref(*args), fused(*args))


def test_map_blind_policy_does_not_read_the_map() -> None:
    """A map-blind file takes the map like any version-2 policy and its action does not depend on it."""
    ref = _policy(3, reads_map=False)
    fused = freeze(fuse_policy(ref), POLICY_ATTRS)
    gen = torch.Generator().manual_seed(11)
    ego, beliefs, mask, sense, fail, demand, target = _one_agent_inputs(gen, 6, 30, 1)
    other = torch.cat([torch.rand(7, 2, generator=gen) * 1500, torch.full((7, 1), 60.0)], 1)
    with torch.no_grad():
        for policy in (ref, fused):
            a = policy(ego, beliefs, mask, sense, fail, demand, target)
            assert torch.equal(a, policy(ego, beliefs, mask, sense, fail, other, target))
            assert torch.equal(a, policy(ego, beliefs, mask, sense, fail, None, target))


def test_policy_without_the_plan_is_not_fused() -> None:
    ref = _policy()
    ref.takes_plan = False
    assert fuse_policy(ref) is ref


@pytest.mark.parametrize("method", ["pl-marl", "gru", "tag-mappo"])
def test_shipped_policies_are_fused_and_agree_with_their_reference(method: str) -> None:
    """The shipped policy.pt's one-agent fast path against the reference it carries (a batch of one)."""
    from pathlib import Path

    lp = load_policy(Path(__file__).resolve().parents[2] / "policies" / method)
    assert is_fused(lp.policy), f"policies/{method}/policy.pt is not the fused form: run python -m plmarl_sitl.learning.nn.convert"
    gen = torch.Generator().manual_seed(9)
    with torch.no_grad():
        for case in range(20):
            args = _one_agent_inputs(gen, 3 + case % 17, 5 + 4 * case, case)
            one = lp.policy(*args)
            batch = lp.policy(*(a[None] for a in args))[0]
            assert float((one - batch).abs().max()) < 1e-4


@pytest.mark.parametrize("reads_map", [True, False], ids=["map", "map-blind"])
def test_fuse_directory_rewrites_an_unfused_directory_in_place(reads_map: bool, tmp_path) -> None:  # noqa: ANN001
    from plmarl_sitl.learning.nn.io import export_policy, quiet_torchscript

    ref = _policy(2, reads_map)
    export_policy(tmp_path, _tracker(), ref, {"method": "pl-marl"})
    with quiet_torchscript():  # write the unfused form, as exports before the fused policy did
        torch.jit.save(freeze(ref, POLICY_ATTRS), str(tmp_path / "policy.pt"))
    from plmarl_sitl.learning.nn.io import sha256

    card = (tmp_path / "card.yaml").read_text().replace(
        (tmp_path / "card.yaml").read_text().split("policy.pt: ")[1].split()[0], sha256(tmp_path / "policy.pt"))
    (tmp_path / "card.yaml").write_text(card)
    assert not is_fused(load_policy(tmp_path).policy)
    new = fuse_directory(tmp_path)
    assert new["export"]["fused"]["policy.pt"] and "fused_from_sha256" in new["export"]
    lp = load_policy(tmp_path)
    assert is_fused(lp.policy) and lp.card["io"]["reads_map"] == reads_map
    gen = torch.Generator().manual_seed(10)
    args = _one_agent_inputs(gen, 4, 9, 1)
    with torch.no_grad():
        assert float((lp.policy(*args) - ref(*args)).abs().max()) < 1e-4
    assert fuse_directory(tmp_path) == lp.card  # nothing left to fuse


def test_fuse_command_bad_directory_is_one_line(tmp_path) -> None:  # noqa: ANN001
    """`python -m plmarl_sitl.learning.nn.convert` on a directory that is not a policy: one line, exit 2."""
    import subprocess
    import sys

    (tmp_path / "card.yaml").write_text("method: [unclosed")
    for arg in (str(tmp_path / "missing"), str(tmp_path)):
        r = subprocess.run([sys.executable, "-m", "plmarl_sitl.learning.nn.convert", arg], capture_output=True, text=True)
        lines = [ln for ln in r.stderr.splitlines() if "Deprecat" not in ln and ln.strip()]
        assert r.returncode == 2 and len(lines) == 1 and lines[0].startswith("convert: error: "), r.stderr
        assert "Traceback" not in r.stderr
    r = subprocess.run([sys.executable, "-m", "plmarl_sitl.learning.nn.convert"], capture_output=True, text=True)
    assert r.returncode == 2 and "usage:" in r.stderr
