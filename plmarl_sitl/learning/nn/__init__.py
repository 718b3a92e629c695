"""Learning modules: predictors, belief tracker, the policy contract and input, attention actor, critic."""

from plmarl_sitl.learning.nn.belief import NEVER, Beliefs, BeliefTracker
from plmarl_sitl.learning.nn.contract import PolicyCall, PolicyForm, PolicyInputs
from plmarl_sitl.learning.nn.features import EGO_FEATURES, FeatureScales, build_policy_input
from plmarl_sitl.learning.nn.policy import Actor, AttentionFusion, Critic, DeployedPolicy, action_to_accel
from plmarl_sitl.learning.nn.predictor import ConstantVelocity, GRUPredictor, KinematicPredictor, make_predictor

__all__ = [
    "NEVER",
    "Beliefs",
    "BeliefTracker",
    "PolicyCall",
    "PolicyForm",
    "PolicyInputs",
    "EGO_FEATURES",
    "FeatureScales",
    "build_policy_input",
    "Actor",
    "AttentionFusion",
    "Critic",
    "DeployedPolicy",
    "action_to_accel",
    "ConstantVelocity",
    "GRUPredictor",
    "KinematicPredictor",
    "make_predictor",
]
