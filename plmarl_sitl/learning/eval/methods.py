"""The evaluation methods by name, what each one is (for --help), and deprecated aliases.

No heavy import here: the command line builds its help from it without loading torch.
"""

from __future__ import annotations

import sys

# One line per method: what it is. The order is the order of --help and of the reports.
METHOD_HELP = {
    "pl-marl": "the letter's method: MLP predictor phi + attention policy (policies/pl-marl)",
    "gru": "GRU predictor + the same policy (policies/gru)",
    "tag-mappo": "no predictor, held states as they are (policies/tag-mappo)",
    "dead-reckoning": "the PL-MARL policy with constant-velocity prediction in its tracker and in its failure re-plans (ablation)",
    "service": "the plan follower: each UAV flies to its point of the team plan, re-planned after failures, no learning (a reference)",
    "service-search": "the plan follower whose team plan places its points by search (placement: search, the default, model/placement.py): the greedy from several first points, improved locally (issue 24.3)",
    "service-greedy": "the plan follower whose team plan places its points by the plain greedy (placement: greedy, the default before session 15)",
    "service-learned": "the plan follower whose team plan's greedy picks are ranked by the learnt scorer (placement: learned, policies/pl-marl/placement.pt)",
    "pl-marl-learned": "the PL-MARL policy on the team plan with the learnt placement (placement: learned)",
    "service-track": "the plan follower whose point moves toward the users the UAV senses, at most 30 m and within the plan's link and spacing bounds (track_sensed_m: 30, model/sensed_track.py): it follows moving crowds between demand maps (issue 24.3, session 19)",
    "pl-marl-track": "the PL-MARL policy on the team plan's point moved toward its sensed users, at most 30 m (track_sensed_m: 30)",
    "pl-marl-resolve": "the PL-MARL policy on the team plan re-solved whole after every failure (failure_replan: resolve: the default until session 27; an ablation of the default's local repairs, model/repairs.py)",
    "service-resolve": "the plan follower on the team plan re-solved whole after every failure (failure_replan: resolve; an ablation)",
    "pl-marl-transit": "the PL-MARL policy on station, the plan follower's command in transit: beyond 300 m from its plan point (transit_plan_m: 300, model/plan_follower.py; for long transits, not the default: see docs/RESULTS.md, session 28)",
    "service-fixed": "the plan follower without failure re-plans (the team plan of before issue 24; an ablation)",
    "service-local": "the plan follower on a neighbourhood plan (coordination: local, model/local_plan.py): each UAV solves a plan of its own region only, a cost that does not grow with N or the area (not the default: see docs/RESULTS.md)",
    "greedy": "greedy clairvoyant placement with global knowledge (a reference; called 'oracle' before)",
    "clairvoyant": "best of several plans re-chosen every decision with true states and users (a reference)",
    "heuristic": "hand-written decentralised controller, local sensing only",
}
ALL_METHODS = tuple(METHOD_HELP)
# old name -> (new name, why), each accepted for one release
DEPRECATED_METHODS = {
    "oracle": ("greedy", "greedy clairvoyant placement: a reference, not a bound"),
    "pl-marl-local-repairs": ("pl-marl", "local failure repairs are the default since session 27; pl-marl-resolve is the old default"),
    "service-local-repairs": ("service", "local failure repairs are the default since session 27; service-resolve is the old default"),
}
# Methods that plan with global knowledge and never read the signalled states: their episodes
# do not depend on T_up, so a sweep runs them once (tests/learning/test_suite.py checks it).
GLOBAL_KNOWLEDGE = ("greedy", "clairvoyant")


def methods_help() -> str:
    """'name: what it is; ...' for a command's description."""
    return "; ".join(f"{m}: {h}" for m, h in METHOD_HELP.items())


def canonical_method(name: str) -> str:
    """The method's current name; a deprecated alias is mapped, with a one-line note on stderr."""
    if name not in DEPRECATED_METHODS:
        return name
    new, why = DEPRECATED_METHODS[name]
    print(f"note: method {name!r} is now {new!r} ({why}); {name!r} is accepted for one more release", file=sys.stderr)
    return new


def parse_methods(text: str) -> list[str]:
    """'a,b,c' -> method names (aliases mapped); ValueError naming the unknown ones."""
    out = [canonical_method(m.strip()) for m in text.split(",") if m.strip()]
    bad = [m for m in out if m not in METHOD_HELP]
    if bad or not out:
        raise ValueError(f"unknown method(s) {', '.join(bad) or '(none)'}; choose from {', '.join(ALL_METHODS)}")
    return list(dict.fromkeys(out))
