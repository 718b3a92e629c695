"""Fused deployment form of the PL-MARL tracker (what `predictor.pt` holds for the MLP
predictor). The fused policy of input version 1 was removed with issue 12's inputs
(relative features, demand map); version 2 policies are exported unfused for now.

At these sizes (M <= 20 neighbours, 32-64 wide layers) a decision costs the TorchScript
interpreter's per-op overhead (~1 us an op), not FLOPs. The training modules
(`BeliefTracker`, `KinematicPredictor`, `DeployedPolicy`) are written for clarity and any
batch shape; these modules compute the SAME function with fewer, fused ops on the
deployed agent's shapes and hand every other shape to the reference module they wrap:

* every fixed linear map is folded into the next layer's weights at export: the feature
  normalisation (`build_policy_input`), the relative displacement (PE input), Encoder + PE
  + W of the attention, phi's input normalisation, and the point-mass integration
  (constant-velocity part) of phi's output;
* one agent (ego (6,), beliefs (M, 6)) runs on `addmv` / `addmm` / `addr` with
  pre-transposed constant weights: one op per layer, bias included, no transposes, no
  concatenation of the P-AoI into phi's input;
* the masked softmax compares against constant tensors (no scalar-to-tensor ops).

The folded constants are built from the eager module (`fuse_tracker`). Outputs equal the
reference module's (tests/learning/test_deploy.py).
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

from plmarl_sitl.learning.nn.belief import MAX_AOI, NEVER, BeliefTracker, backfill
from plmarl_sitl.learning.nn.predictor import KinematicPredictor

DEPLOY_FORM = "fused-v1"  # attribute of a fused file (kept by freezing)


def is_fused(module: nn.Module) -> bool:
    return getattr(module, "deploy_form", None) == DEPLOY_FORM


class FusedKinematicTracker(nn.Module):
    """`BeliefTracker(KinematicPredictor)` with phi folded; same API and state tensors.

    Fast path: one agent, held_state (M, 6) with M >= 1. Other shapes run `self.ref`.
    """

    def __init__(self, ref: nn.Module, w1: torch.Tensor, b1: torch.Tensor, w2: torch.Tensor, b2: torch.Tensor,
                 w3: torch.Tensor, b3: torch.Tensor, kg: torch.Tensor) -> None:
        super().__init__()
        self.ref = ref  # the reference BeliefTracker (eager, or a loaded TorchScript file)
        self.deploy_form = DEPLOY_FORM
        self.buffer_len = int(ref.buffer_len)
        self.dt = float(ref.dt)
        self.half_never = NEVER * 0.5
        self.max_aoi = MAX_AOI
        self.tail = self.buffer_len - 1
        # phi in its sigmoid form, with exactly the constants KinematicPredictor.forward
        # computes (so the fused tracker is bit-identical to the eager one on one agent).
        w1, b1 = w1.detach().float(), b1.detach().float()  # (hid, L*6 + 1): l1 with the input normalisation folded
        w2, b2 = w2.detach().float(), b2.detach().float()
        w3, b3 = w3.detach().float(), b3.detach().float()
        self.w1, self.b1 = w1 * 2.0, b1 * 2.0
        self.w2, self.b2 = w2 * 4.0, (b2 - w2.sum(1)) * 2.0
        self.w3, self.b3 = w3 * 2.0, b3 - w3.sum(1)
        self.kg = kg.detach().float().clone()  # (9, 6): [newest state, u] -> next state
        self.zero = torch.tensor(0.0)

    @torch.jit.export
    def init_state(self, held_state: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.ref.init_state(held_state)

    def forward(
        self, t: float, held_state: torch.Tensor, held_t_rx: torch.Tensor, buf: torch.Tensor, seen_t_rx: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        if held_state.dim() != 2 or held_state.size(0) == 0:
            return self.ref(t, held_state, held_t_rx, buf, seen_t_rx)
        d = torch.sub(torch.scalar_tensor(t), held_t_rx)  # t - t_rx, no wrapped-scalar cast
        gap = held_t_rx - seen_t_rx  # > 0: newer than the state last taken; > 5e8: never taken before
        fresh = torch.ge(d, self.zero).logical_and_(gap > self.zero)
        aoi = d.clamp_(1.0, self.max_aoi)  # Eq. (1), capped
        x = torch.cat([buf.flatten(1), aoi.unsqueeze(1)], 1)
        s1 = F.linear(x, self.w1, self.b1).sigmoid_()  # in place: no output allocation
        s2 = F.linear(s1, self.w2, self.b2).sigmoid_()
        u = F.linear(s2, self.w3, self.b3).tanh_()
        pred = torch.cat([buf.select(1, -1), u], 1) @ self.kg
        belief = torch.where(fresh.unsqueeze(-1), held_state, pred)
        new_buf = torch.cat([buf.narrow(1, 1, self.tail), belief.unsqueeze(1)], 1)
        # Back-fill only when some slot is heard for the first time (exact check inside);
        # a slot never heard (e.g. the agent's own) has gap 0 and costs nothing.
        if gap.max().item() > -self.half_never:
            new_buf = backfill(new_buf, held_state, fresh, seen_t_rx <= self.half_never, self.dt)
        return belief, aoi, new_buf, torch.where(fresh, held_t_rx, seen_t_rx)


def fuse_tracker(tracker: BeliefTracker) -> nn.Module:
    """The fused tracker for phi (KinematicPredictor); other predictors are returned as they are."""
    p = getattr(tracker, "predictor", None)
    if is_fused(tracker) or not isinstance(tracker, BeliefTracker) or not isinstance(p, KinematicPredictor):
        return tracker
    with torch.no_grad():
        w1 = p.l1.weight @ p.T.t()
    return FusedKinematicTracker(tracker.eval(), w1, p.l1.bias, p.l2.weight, p.l2.bias, p.l3.weight, p.l3.bias, p.KG)
