"""Frozen-dataclass configuration and strict YAML loading.

Every file the toolkit reads (missions, vehicle models, policy cards) goes through
`from_dict`, which rejects unknown keys and wrong types and names the failing path the way
a user would write it (`failures[2].at_s: must be >= 0`). Validation rules live next to the
fields as `metadata={"min": ..}` / `__post_init__` checks so the schema is in one place.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, TypeVar

import yaml

from plmarl_sitl.errors import UserError

T = TypeVar("T")

REPO_ROOT = Path(__file__).resolve().parent.parent
# The project's own files, defaults that must work from any directory (a user running
# `plmarl suite` or `plmarl eval` outside the checkout means these, not ./policies).
PROJECT_POLICIES = REPO_ROOT / "policies"
PROJECT_MISSIONS = REPO_ROOT / "missions"
PAPER_MISSION = PROJECT_MISSIONS / "paper_urban.yaml"
PROJECT_SUITE = PROJECT_MISSIONS / "suite" / "suite.yaml"


# Seeds are unsigned 32-bit: every generator the toolkit seeds (torch, numpy, the link
# emulator's) takes them, and so do the offsets training and the suite add (learning/train/seeds.py).
MAX_SEED = 2**32 - 1


class ConfigError(UserError, ValueError):
    """A configuration value is wrong. `path` is the dotted path to it, `reason` says why.
    A user error: the file the user gave needs fixing."""

    def __init__(self, path: str, reason: str, source: str | None = None) -> None:
        self.path = path
        self.reason = reason
        self.source = source
        prefix = ": ".join(_one_line(x) for x in (source, path) if x)
        super().__init__(f"{prefix}: {_one_line(reason)}" if prefix else _one_line(reason))


def _one_line(text: str) -> str:
    """text with its control characters escaped: a YAML key may hold a newline (`"\\n": 1`), and the
    error naming it must stay one line."""
    return text if text.isprintable() else "".join(c if c.isprintable() else c.encode("unicode_escape").decode("ascii")
                                                   for c in text)


def _join(path: str, key: str | int) -> str:
    if isinstance(key, int):
        return f"{path}[{key}]"
    return f"{path}.{key}" if path else key


def _type_name(tp: Any) -> str:
    names = {int: "an integer", float: "a number", str: "a string", bool: "true or false"}
    if tp in names:
        return names[tp]
    if dataclasses.is_dataclass(tp):
        return "a mapping"
    return getattr(tp, "__name__", str(tp))


def _convert(value: Any, tp: Any, path: str) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if tp is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        errors = []
        for a in inner:
            try:
                return _convert(value, a, path)
            except ConfigError as exc:
                errors.append(exc.reason)
        raise ConfigError(path, " or ".join(dict.fromkeys(errors)))
    if origin is Literal:
        if value not in args:
            raise ConfigError(path, f"expected one of {', '.join(map(repr, args))}, got {value!r}")
        return value
    if origin in (tuple, list):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(path, "expected a list")
        if origin is tuple and args and args[-1] is not Ellipsis:
            if len(value) != len(args):
                raise ConfigError(path, f"expected a list of {len(args)} items, got {len(value)}")
            return tuple(_convert(v, a, _join(path, i)) for i, (v, a) in enumerate(zip(value, args, strict=True)))
        item_tp = args[0] if args else Any
        return tuple(_convert(v, item_tp, _join(path, i)) for i, v in enumerate(value))
    if dataclasses.is_dataclass(tp):
        return from_dict(tp, value, path)
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(path, "expected true or false")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(path, "expected an integer")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(path, "expected a number")
        if not math.isfinite(value):
            raise ConfigError(path, "expected a finite number")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(path, "expected a string")
        return value
    raise TypeError(f"unsupported config type {tp!r} at {path}")


def _check_bounds(f: dataclasses.Field, value: Any, path: str) -> None:
    lo, hi = f.metadata.get("min"), f.metadata.get("max")
    if value is None or not isinstance(value, (int, float)):
        return
    if lo is not None and value < lo:
        raise ConfigError(path, f"must be >= {lo}")
    if hi is not None and value > hi:
        raise ConfigError(path, f"must be <= {hi}")


def from_dict(cls: type[T], data: Any, path: str = "") -> T:
    """Build dataclass `cls` from plain data, strictly. Raises ConfigError naming the path."""
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(path, "expected a mapping")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = [k for k in data if k not in fields]
    if unknown:
        raise ConfigError(
            _join(path, str(unknown[0])),
            f"unknown key (allowed: {', '.join(sorted(fields))})",
        )
    kwargs = {}
    for name, f in fields.items():
        sub = _join(path, name)
        if name not in data:
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise ConfigError(sub, "is required")
            continue
        value = _convert(data[name], hints[name], sub)
        _check_bounds(f, value, sub)
        kwargs[name] = value
    try:
        return cls(**kwargs)
    except ConfigError as exc:
        raise ConfigError(_join(path, exc.path) if exc.path else path, exc.reason) from None


def to_dict(obj: Any) -> Any:
    """The plain-data form of a config dataclass (tuples become lists), for YAML/JSON."""
    if dataclasses.is_dataclass(obj):
        return {f.name: to_dict(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, (list, tuple)):
        return [to_dict(v) for v in obj]
    return obj


# What a configuration file may be. Missions, vehicle models, cards and suite files are a few
# KB; anything far larger, deeper or more aliased is a mistake or an attack, and would cost
# minutes or a RecursionError before a schema error could name it.
MAX_CONFIG_BYTES = 1 << 20
MAX_CONFIG_DEPTH = 32
MAX_CONFIG_NODES = 100_000  # values after expanding aliases (a "billion laughs" file has 10^9)


class _StrictLoader(getattr(yaml, "CSafeLoader", yaml.SafeLoader)):  # libyaml's parser where PyYAML has it (~10x)
    """yaml's safe loader that refuses a mapping with a key given twice (PyYAML keeps the
    last one silently: `seed: 1` then `seed: 2` would fly seed 2 without a word)."""

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict:
        seen: set = set()
        for key_node, _ in node.value:
            key = self.construct_object(key_node, deep=True)
            try:
                dup = key in seen
            except TypeError:  # an unhashable key: the base class says so in its own words
                break
            if dup:
                raise yaml.constructor.ConstructorError(
                    None, None, f"duplicate key {key!r}", key_node.start_mark)
            seen.add(key)
        return super().construct_mapping(node, deep=deep)


def _check_shape(root: yaml.Node | None) -> None:
    """Refuse a document nested deeper than MAX_CONFIG_DEPTH or larger than MAX_CONFIG_NODES
    values once aliases are expanded; iterative, so a pathological file cannot overflow the stack."""
    if root is None:
        return
    size: dict[int, int] = {}  # node id -> expanded size (aliases share nodes: memoised)
    stack: list[tuple[yaml.Node, int, bool]] = [(root, 1, False)]
    while stack:
        node, depth, done = stack.pop()
        if depth > MAX_CONFIG_DEPTH:
            raise ValueError(f"nested more than {MAX_CONFIG_DEPTH} levels deep (line {node.start_mark.line + 1})")
        if id(node) in size:
            continue
        children = ([v for kv in node.value for v in kv] if isinstance(node, yaml.MappingNode)
                    else list(node.value) if isinstance(node, yaml.SequenceNode) else [])
        if done or not children:
            size[id(node)] = 1 + sum(size[id(c)] for c in children)
            if size[id(node)] > MAX_CONFIG_NODES:
                raise ValueError(f"more than {MAX_CONFIG_NODES} values once its aliases are expanded")
            continue
        stack.append((node, depth, True))
        stack.extend((c, depth + 1, False) for c in children if id(c) not in size)


def _yaml_reason(exc: yaml.YAMLError) -> str:
    """A YAML error on one line: what is wrong and where (PyYAML's own text spans several)."""
    mark = getattr(exc, "problem_mark", None)
    problem = getattr(exc, "problem", None) or getattr(exc, "reason", None) or " ".join(str(exc).split())
    return f"{problem} (line {mark.line + 1}, column {mark.column + 1})" if mark is not None else problem


def read_yaml(path: str | Path) -> Any:
    """The plain data of a configuration file, read strictly: at most MAX_CONFIG_BYTES of
    UTF-8, no key twice in a mapping, no pathological nesting or alias expansion. Every
    refusal is one ConfigError naming the file."""
    path = Path(path)
    src = str(path)
    try:
        with path.open("rb") as f:
            raw = f.read(MAX_CONFIG_BYTES + 1)
    except OSError as exc:
        raise ConfigError("", f"cannot read file: {exc.strerror}", src) from exc
    if len(raw) > MAX_CONFIG_BYTES:
        raise ConfigError("", f"larger than {MAX_CONFIG_BYTES >> 10} KiB: not a configuration file", src)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError("", f"not UTF-8 text (byte 0x{raw[exc.start]:02x} at offset {exc.start})", src) from None
    loader = None
    try:
        loader = _StrictLoader(text)  # the reader refuses non-printable characters here
        node = loader.get_single_node()
        _check_shape(node)
        return None if node is None else loader.construct_document(node)
    except yaml.YAMLError as exc:
        raise ConfigError("", f"not valid YAML: {_yaml_reason(exc)}", src) from None
    except (ValueError, RecursionError) as exc:
        reason = str(exc) if isinstance(exc, ValueError) else f"nested more than {MAX_CONFIG_DEPTH} levels deep"
        raise ConfigError("", f"not a configuration file: {reason}", src) from None
    finally:
        if loader is not None:
            loader.dispose()


def load_yaml(cls: type[T], path: str | Path) -> T:
    """Load and validate a YAML file into `cls`; every error names the file and the key path."""
    path = Path(path)
    data = read_yaml(path)
    try:
        return from_dict(cls, data)
    except ConfigError as exc:
        raise ConfigError(exc.path, exc.reason, str(path)) from None


def _require(cond: bool, path: str, reason: str) -> None:
    if not cond:
        raise ConfigError(path, reason)


# --------------------------------------------------------------------------------------
# Vehicle model
# --------------------------------------------------------------------------------------


@dataclass(frozen=True)
class VehicleModel:
    """Point-mass limits of one airframe (vehicle_models/<name>.yaml)."""

    name: str
    max_speed_mps: float = field(default=20.0, metadata={"min": 0.1})
    max_accel_mps2: float = field(default=5.0, metadata={"min": 0.1})
    # The operating band the mission flies in (AGL). Below min_alt the coverage
    # geometry is meaningless for the A2G model; the autopilot still lands to 0.
    min_alt_m: float = field(default=30.0, metadata={"min": 0.0})
    max_alt_m: float = field(default=200.0, metadata={"min": 1.0})
    takeoff_alt_m: float = field(default=60.0, metadata={"min": 1.0})
    max_climb_mps: float = field(default=5.0, metadata={"min": 0.1})

    def __post_init__(self) -> None:
        _require(self.max_alt_m > self.min_alt_m, "max_alt_m", "must be > min_alt_m")
        _require(
            self.min_alt_m <= self.takeoff_alt_m <= self.max_alt_m,
            "takeoff_alt_m",
            "must lie inside [min_alt_m, max_alt_m]",
        )


# Vehicle models read so far, by (resolved path, mtime, size): `Mission.vehicle_model()` is
# asked five times while an agent starts (issue 25: 100 agents' start-up), and a SITL
# swarm's forkserver reads the file once for every agent it forks. VehicleModel is frozen.
_vehicles: dict[tuple[str, int, int], VehicleModel] = {}


def load_vehicle(name_or_path: str | Path) -> VehicleModel:
    """A vehicle model by file path or by name in vehicle_models/ (read once per file version)."""
    p = Path(name_or_path)
    if not p.suffix:
        p = REPO_ROOT / "vehicle_models" / f"{name_or_path}.yaml"
    try:
        st = p.stat()
    except OSError:
        return load_yaml(VehicleModel, p)  # its own clear error
    key = (str(p.resolve()), st.st_mtime_ns, st.st_size)
    if key not in _vehicles:
        _vehicles[key] = load_yaml(VehicleModel, p)
    return _vehicles[key]
