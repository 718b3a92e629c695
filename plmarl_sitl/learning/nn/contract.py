"""The one typed policy contract (docs/POLICY_IO.md): what a policy decides from, which call a
policy file takes, and the one adapter between the two.

* `PolicyInputs`: the inputs of one decision (an agent's, or the twin's (B, N) batch), a
  TorchScript-safe NamedTuple. The perception steps build it (the twin's and the trainer's:
  `perception.Perception`; the deployed agent's: `deploy/agent/decision.py`), the feature step
  reads it (`features.build_policy_input`, compiled into every exported policy).
* `PolicyForm`: which call a policy file takes. The ONLY place that reads the file's
  `input_version`, `takes_plan` and `reads_map` attributes to decide how to call it (the
  fused forms copy them, the card records them).
* `PolicyCall`: `policy.pt` behind the typed call, `accel = call(inputs)`. The ONLY place that
  maps `PolicyInputs` onto a file's positional inputs (5, 6 or 7 of them).

Why the files keep their positional forward (and new exports too): every shipped file has it
and must keep loading, so the adapter cannot go away; one file format is one contract for a
deployment that does not run Python (a TorchScript runtime calls `forward` with tensors);
a forward that takes `PolicyInputs` scripts and loads (tests/learning/test_contract.py), so
the choice is open if the positional form is ever dropped.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple, Optional

import torch

INPUT_VERSION = 2  # what new exports take; 1: absolute positions, no demand map (policies before issue 12)


class PolicyInputs(NamedTuple):
    """One decision's inputs, physical units in the mission frame (docs/POLICY_IO.md).

    ego (..., 6) own state; beliefs (..., M, 6) the tracker's; mask (..., M) bool: j in N_i;
    sense (..., SENSING_FEATURES); fail (...) bool: the failure state f of the file's rule
    (`PolicyForm.predicted_fail`); demand (..., K, 3) with ego's leading shape, None before
    the first map; target (..., 2) the team plan's point, None before the first map.
    """

    ego: torch.Tensor
    beliefs: torch.Tensor
    mask: torch.Tensor
    sense: torch.Tensor
    fail: torch.Tensor
    demand: Optional[torch.Tensor] = None  # noqa: UP045 - TorchScript needs Optional
    target: Optional[torch.Tensor] = None  # noqa: UP045


@dataclass(frozen=True)
class PolicyForm:
    """Which call a policy takes (docs/POLICY_IO.md):

    * input version 1 (policies/wave1/*, before issue 12): (ego, beliefs, mask, sense, fail)
      with f = "a neighbour was dropped", no map, no plan;
    * input version 2: + demand, with f = predicted in range yet silent
      (`model.signalling.silent_in_range`);
    * input version 2 with `takes_plan`: + the team plan's target.
    """

    input_version: int
    takes_plan: bool
    reads_map: bool  # False: a map-blind actor (takes demand, reads it only through the plan)

    @classmethod
    def of(cls, policy: object) -> PolicyForm:
        """A policy file's form from its attributes (files without them: version 1, no plan;
        version 2 without `reads_map` reads the map)."""
        version = int(getattr(policy, "input_version", 1))
        return cls(version, bool(getattr(policy, "takes_plan", False)), bool(getattr(policy, "reads_map", version >= 2)))

    @classmethod
    def trained(cls, reads_map: bool) -> PolicyForm:
        """The form of what `plmarl train` trains and exports now (`policy.DeployedPolicy`)."""
        return cls(INPUT_VERSION, True, reads_map)

    @property
    def takes_demand(self) -> bool:
        """Called with the demand map (the agent waits for a map due at a decision)."""
        return self.input_version >= 2

    @property
    def predicted_fail(self) -> bool:
        """f by the predicted-in-range rule (True) or "a neighbour was dropped" (version 1)."""
        return self.input_version >= 2

    @property
    def arity(self) -> int:
        """How many of `PolicyInputs`' fields, in order, the file's forward takes."""
        if self.input_version < 2:
            return 5
        return 7 if self.takes_plan else 6


class PolicyCall:
    """A policy module behind the typed call: `PolicyCall(policy)(inputs) -> accel (..., 3)`.

    The form is read once here (attribute reads on a ScriptModule are slow, and the decision
    path is hot); a call is one tuple slice on top of the file's own call.
    """

    def __init__(self, policy: torch.nn.Module) -> None:
        self.module = policy
        self.form = PolicyForm.of(policy)
        self.arity = self.form.arity

    def __call__(self, inputs: PolicyInputs) -> torch.Tensor:
        return self.module(*inputs[: self.arity])
