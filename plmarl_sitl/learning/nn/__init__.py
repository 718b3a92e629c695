"""Learning modules: predictors, belief tracker, the policy contract and input, attention actor, critic.

The names below are imported on first use (PEP 562), not with the package: a deployed agent
imports `learning.nn.io`/`contract`/`features` and never the training modules (belief tracker,
actor, predictors) these names come from, and a forked agent's RSS counts every module its
forkserver holds (issue 24.2)."""

from importlib import import_module

_WHERE = {
    "NEVER": "belief",
    "Beliefs": "belief",
    "BeliefTracker": "belief",
    "PolicyCall": "contract",
    "PolicyForm": "contract",
    "PolicyInputs": "contract",
    "EGO_FEATURES": "features",
    "FeatureScales": "features",
    "build_policy_input": "features",
    "Actor": "policy",
    "AttentionFusion": "policy",
    "Critic": "policy",
    "DeployedPolicy": "policy",
    "action_to_accel": "policy",
    "ConstantVelocity": "predictor",
    "GRUPredictor": "predictor",
    "KinematicPredictor": "predictor",
    "make_predictor": "predictor",
}

__all__ = list(_WHERE)


def __getattr__(name: str) -> object:
    if name not in _WHERE:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(import_module(f"{__name__}.{_WHERE[name]}"), name)


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_WHERE))
