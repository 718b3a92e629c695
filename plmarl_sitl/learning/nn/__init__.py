"""Learning modules: predictors, belief tracker, policy input, attention actor, critic."""

from plmarl_sitl.learning.nn.belief import NEVER, Beliefs, BeliefTracker
from plmarl_sitl.learning.nn.features import EGO_FEATURES, FeatureScales, build_policy_input
from plmarl_sitl.learning.nn.policy import Actor, AttentionFusion, Critic, DeployedPolicy, action_to_accel
from plmarl_sitl.learning.nn.predictor import ConstantVelocity, GRUPredictor, KinematicPredictor, make_predictor

__all__ = [
    "NEVER",
    "Beliefs",
    "BeliefTracker",
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
