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


class ConfigError(UserError, ValueError):
    """A configuration value is wrong. `path` is the dotted path to it, `reason` says why.
    A user error: the file the user gave needs fixing."""

    def __init__(self, path: str, reason: str, source: str | None = None) -> None:
        self.path = path
        self.reason = reason
        self.source = source
        prefix = ": ".join(x for x in (source, path) if x)
        super().__init__(f"{prefix}: {reason}" if prefix else reason)


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


# libyaml's parser when PyYAML was built with it: the same safe constructors and
# resolvers (they are Python either way), ~10x faster; every agent of a swarm reads its
# mission and vehicle files at start (issue 25).
_SAFE_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def safe_load_yaml(text: str) -> Any:
    """`yaml.safe_load`, with libyaml's parser where available."""
    return yaml.load(text, Loader=_SAFE_LOADER)  # noqa: S506 - a safe loader


def load_yaml(cls: type[T], path: str | Path) -> T:
    """Load and validate a YAML file into `cls`; every error names the file and the key path."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise ConfigError("", f"cannot read file: {exc.strerror}", str(path)) from exc
    try:
        data = safe_load_yaml(text)
    except yaml.YAMLError as exc:
        raise ConfigError("", f"not valid YAML: {exc}", str(path)) from exc
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


def load_vehicle(name_or_path: str | Path) -> VehicleModel:
    """A vehicle model by file path or by name in vehicle_models/."""
    p = Path(name_or_path)
    if not p.suffix:
        p = REPO_ROOT / "vehicle_models" / f"{name_or_path}.yaml"
    return load_yaml(VehicleModel, p)
