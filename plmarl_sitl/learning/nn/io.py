"""TorchScript export and checked loading of trained policies (policies/<method>/).

A policy directory holds:

* predictor.pt  the scripted `BeliefTracker` (Algorithm 1) with the method's predictor
                inside: `forward(t, held_state, held_t_rx, buf, seen_t_rx)` and
                `init_state(held_state)`;
* policy.pt     the scripted `DeployedPolicy` (or its fused form, `fused.py`):
                `forward(ego, beliefs, mask, sense, fail_flag, demand, target) -> accel`,
                input features included (input version 2; call it through
                `contract.PolicyCall` with `contract.PolicyInputs`);
* card.yaml     method, config, seed, git commit, training wall time, evaluation
                numbers, the I/O contract constants and each file's sha256.

docs/POLICY_IO.md is the contract. TorchScript is deprecated in torch 2.13 and warns on
every script/save/load; it is still the format we ship, so these helpers silence exactly
those DeprecationWarnings (`quiet_torchscript()`), nothing else.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import torch
import yaml
from torch import nn

from plmarl_sitl.config import ConfigError, read_yaml
from plmarl_sitl.errors import PolicyFileError
from plmarl_sitl.learning.nn.card import check_card
from plmarl_sitl.learning.nn.contract import INPUT_VERSION, PolicyCall, PolicyForm, PolicyInputs
from plmarl_sitl.learning.nn.features import EGO_FEATURES, STATE_DIM
from plmarl_sitl.model.coverage import SENSING_FEATURES
from plmarl_sitl.model.demand import DEMAND_CELL_FIELDS

CARD_VERSION = 2  # 2: policy input version 2 (relative inputs, demand map; issue 12)
# Card versions that load. Version 1 (input version 1: absolute positions, no demand map,
# the raw fail flag) still loads so a deployment can fly the policies shipped before issue 12.
LOADABLE_CARD_VERSIONS = (1, 2)
FILES = ("predictor.pt", "policy.pt", "card.yaml")


@contextlib.contextmanager
def quiet_torchscript() -> Iterator[None]:
    """Silence torch 2.13's TorchScript deprecation warnings (and only those)."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r".*torch\.jit\..* is deprecated.*", category=DeprecationWarning)
        warnings.filterwarnings("ignore", message=r".*TorchScript.*deprecated.*")
        yield


def script(module: nn.Module) -> torch.jit.ScriptModule:
    with quiet_torchscript():
        return torch.jit.script(module.eval())


TRACKER_ATTRS = ["init_state", "buffer_len", "dt"]
SCALES = ["alt_max", "v_max", "a_max", "r_comm", "claim_m", "demand_unit"]
POLICY_ATTRS = SCALES + ["input_version", "takes_plan", "reads_map"]
# Scales that describe the scenario, not the vehicle, radio or sensor: the policy keeps the
# value it was trained with as its own unit (demand_unit: users per unit of the demand map's
# counts), so a mission with other cluster sizes flies it instead of being refused.
SCENARIO_SCALES = ("demand_unit",)


def freeze(module: nn.Module, keep: list[str]) -> torch.jit.ScriptModule:
    """Script and freeze (weights and attributes become constants: fewer interpreter ops
    per call, which is most of the cost at these sizes), keeping the public API `keep`."""
    keep = [a for a in keep if hasattr(module, a)] + [a for a in ("deploy_form",) if hasattr(module, a)]
    with quiet_torchscript():
        return torch.jit.freeze(torch.jit.script(module.eval()), preserved_attrs=keep)


def sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def export_policy(out_dir: str | Path, tracker: nn.Module, policy: nn.Module, card: dict) -> Path:
    """Script and save tracker and policy, then write card.yaml (with the files' sha256)."""
    # Imported here, not at the top: the fused modules (and the training modules they build on)
    # are for export; an agent, which only loads, does not hold them (its RSS, issue 24.2).
    from plmarl_sitl.learning.nn.fused import fuse_policy, fuse_tracker

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    tracker = fuse_tracker(tracker)  # unchanged if not fusable (GRU, hold, scripted)
    policy = fuse_policy(policy)  # unchanged if not fusable (no plan input, scripted)
    with quiet_torchscript():
        # A tracker loaded from a policy's predictor.pt (`plmarl train --predictor`) is frozen already: saved as it is.
        frozen = isinstance(tracker, torch.jit.ScriptModule) and not list(tracker.parameters())
        torch.jit.save(tracker if frozen else freeze(tracker, TRACKER_ATTRS), str(out / "predictor.pt"))
        torch.jit.save(freeze(policy, POLICY_ATTRS), str(out / "policy.pt"))
    card = dict(card)
    form = PolicyForm.of(policy)
    card["card_version"] = CARD_VERSION
    card["io"] = {
        "state_dim": STATE_DIM,
        "sense_dim": SENSING_FEATURES,
        "ego_features": EGO_FEATURES,
        "input_version": INPUT_VERSION,
        "takes_plan": form.takes_plan,
        "reads_map": form.reads_map,
        "demand_cell_fields": DEMAND_CELL_FIELDS,
        "buffer_len": int(tracker.buffer_len),  # type: ignore[arg-type]
        "dt_s": float(tracker.dt),  # type: ignore[arg-type]
        "scales": {k: float(getattr(policy, k)) for k in SCALES},
    }
    card["sha256"] = {f: sha256(out / f) for f in ("predictor.pt", "policy.pt")}
    (out / "card.yaml").write_text(yaml.safe_dump(card, sort_keys=False))
    return out


@dataclass(frozen=True)
class LoadedPolicy:
    directory: Path
    tracker: torch.jit.ScriptModule
    policy: torch.jit.ScriptModule
    card: dict

    @functools.cached_property
    def form(self) -> PolicyForm:
        return PolicyForm.of(self.policy)

    @functools.cached_property
    def call(self) -> PolicyCall:
        """The policy behind the typed call: `lp.call(PolicyInputs(...)) -> accel`."""
        return PolicyCall(self.policy)

    @property
    def input_version(self) -> int:
        return self.form.input_version

    @property
    def takes_plan(self) -> bool:
        return self.form.takes_plan


def _load_card(path: Path) -> dict:
    if not path.is_file():
        raise PolicyFileError(str(path), "missing (every policy directory needs card.yaml)")
    try:
        card = read_yaml(path)
        check_card(card)
    except ConfigError as exc:
        raise PolicyFileError(str(path), f"corrupt: {exc.path + ': ' if exc.path else ''}{exc.reason}") from None
    if card["card_version"] not in LOADABLE_CARD_VERSIONS:
        raise PolicyFileError(str(path), f"card_version {card['card_version']} is not supported (expected one of {LOADABLE_CARD_VERSIONS})")
    return card


def _load_script(path: Path, card: dict) -> torch.jit.ScriptModule:
    if not path.is_file():
        raise PolicyFileError(str(path), "missing")
    want = card["sha256"].get(path.name)
    if want is not None and sha256(path) != want:
        raise PolicyFileError(str(path), "does not match card.yaml (sha256 differs): the file was replaced or damaged")
    try:
        with quiet_torchscript():
            return torch.jit.load(str(path), map_location="cpu")
    except Exception as exc:  # torch raises RuntimeError/ValueError/zip errors for junk
        raise PolicyFileError(str(path), f"corrupt: not a loadable TorchScript file ({type(exc).__name__}: {str(exc).splitlines()[0]})") from exc


def load_policy(directory: str | Path, mission=None) -> LoadedPolicy:  # noqa: ANN001
    """Load and check a policy directory; with `mission`, also check it was made for it.

    Raises PolicyFileError naming the file and the problem: missing, corrupt, a sha256
    that does not match the card, or constants (buffer length, normalisation) that do not
    match the card or the mission. Finally both modules are run once on dummy inputs.
    """
    d = Path(directory)
    if not d.is_dir():
        raise PolicyFileError(str(d), "missing policy directory (expected predictor.pt, policy.pt, card.yaml)")
    card = _load_card(d / "card.yaml")
    tracker = _load_script(d / "predictor.pt", card)
    policy = _load_script(d / "policy.pt", card)
    io = card["io"]
    try:
        buffer_len, scales = int(tracker.buffer_len), {k: float(getattr(policy, k)) for k in io["scales"]}
    except (AttributeError, RuntimeError) as exc:
        raise PolicyFileError(str(d / "policy.pt"), f"mismatched: not a PL-MARL policy/tracker ({exc})") from exc
    call = PolicyCall(policy)
    version = call.form.input_version
    if version != io.get("input_version", 1):
        raise PolicyFileError(str(d / "policy.pt"), f"mismatched: input version {version}, card.yaml says {io.get('input_version', 1)}")
    if buffer_len != io["buffer_len"]:
        raise PolicyFileError(str(d / "predictor.pt"), f"mismatched: buffer length {buffer_len}, card.yaml says {io['buffer_len']}")
    for k, v in scales.items():
        if abs(v - io["scales"][k]) > 1e-6:
            raise PolicyFileError(str(d / "policy.pt"), f"mismatched: scale {k} = {v}, card.yaml says {io['scales'][k]}")
    if mission is not None:
        from plmarl_sitl.learning.nn.features import FeatureScales

        ms = FeatureScales.from_mission(mission)._asdict() | {"area_n": mission.area.north_m, "area_e": mission.area.east_m}  # v1: area
        for k, v in scales.items():
            if k in SCENARIO_SCALES:
                continue
            if abs(v - ms[k]) > 1e-6:
                raise PolicyFileError(str(d / "policy.pt"), f"mismatched with mission {mission.name!r}: {k} = {v}, mission has {ms[k]}")
        if buffer_len != mission.signalling.buffer_len:
            raise PolicyFileError(
                str(d / "predictor.pt"), f"mismatched with mission {mission.name!r}: buffer length {buffer_len}, mission has {mission.signalling.buffer_len}"
            )
    try:
        dry_run(tracker, call)
    except RuntimeError as exc:
        raise PolicyFileError(str(d), f"mismatched: a dry run of predictor.pt -> policy.pt failed ({str(exc).splitlines()[0]})") from exc
    return LoadedPolicy(d, tracker, policy, card)


def dry_run(tracker: torch.jit.ScriptModule, call: PolicyCall) -> None:
    """Run the tracker (init_state, forward) and the policy once on dummy inputs (2 neighbours,
    one demand cell). TorchScript's profiling executor profiles a method's first call and
    optimizes its graph on the second, from that profile, whatever the inputs."""
    with torch.no_grad():
        held = torch.zeros(2, STATE_DIM)
        buf, seen = tracker.init_state(held)
        belief, _, _, _ = tracker(0.0, held, torch.zeros(2), buf, seen)
        call(PolicyInputs(torch.zeros(STATE_DIM), belief, torch.ones(2, dtype=torch.bool), torch.zeros(SENSING_FEATURES),
                          torch.tensor(False), torch.zeros(1, DEMAND_CELL_FIELDS), torch.zeros(2)))
