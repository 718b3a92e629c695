"""Where the deployed agent's coordination is chosen: the mission's `coordination`.

`team` (default): `plan.AgentPlan`, this agent's copy of the whole team's plan
(model/service.py). `local`: `local_plan.LocalAgentPlan`, a plan of its own neighbourhood
(model/local_plan.py), whose cost does not grow with N or the area. The twin chooses the
same way in `learning/nn/plan.py::ServiceTargets.of`."""

from __future__ import annotations

from plmarl_sitl.mission import Mission
from plmarl_sitl.model.gossip import Knowledge


def agent_plan(mission: Mission, me: int, knowledge: Knowledge | None = None):  # noqa: ANN201 - AgentPlan | LocalAgentPlan
    if mission.coordination == "local":
        from plmarl_sitl.deploy.agent.local_plan import LocalAgentPlan

        return LocalAgentPlan(mission, me, knowledge)
    from plmarl_sitl.deploy.agent.plan import AgentPlan

    return AgentPlan(mission, me, knowledge)
