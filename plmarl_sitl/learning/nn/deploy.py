"""Fused deployment forms of the PL-MARL tracker and policy (what `predictor.pt` and
`policy.pt` hold for the MLP predictor and the attention actor).

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

The folded constants are built from the eager modules (`fuse_tracker`, `fuse_policy`) or
read back from an already exported (frozen) file (`fused_from_files`), so shipped policies
can be re-exported without their training checkpoints. Outputs equal the reference
modules' to float32 rounding (tests/learning/test_deploy.py).
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import nn
from torch.nn import functional as F

from plmarl_sitl.learning.nn.belief import MAX_AOI, NEVER, BeliefTracker, backfill
from plmarl_sitl.learning.nn.features import EGO_FEATURES, state_norm
from plmarl_sitl.learning.nn.policy import DeployedPolicy
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


class FusedPolicy(nn.Module):
    """`DeployedPolicy` with normalisation, PE input, Encoder + PE + W folded; same API.

    Fast path: one agent, ego (6,). Other shapes run `self.ref`.
    """

    def __init__(self, ref: nn.Module, consts: dict[str, torch.Tensor]) -> None:
        super().__init__()
        self.ref = ref  # the reference DeployedPolicy (eager, or a loaded TorchScript file)
        self.deploy_form = DEPLOY_FORM
        self.area_n, self.area_e, self.alt_max = float(ref.area_n), float(ref.area_e), float(ref.alt_max)
        self.v_max, self.a_max, self.r_comm = float(ref.v_max), float(ref.a_max), float(ref.r_comm)
        c = {k: v.detach().float() for k, v in consts.items()}
        norm = state_norm(self.area_n, self.area_e, self.alt_max, self.v_max)
        scale, offset = norm[0], norm[1]
        r = 1.0 / self.r_comm  # as DeployedPolicy.inv_r_comm
        n_ego = EGO_FEATURES  # raw input x = [ego (6), sense (4), fail (1)]
        # ego_x = x * s + o
        s = torch.ones(n_ego)
        s[:6] = scale
        o = torch.zeros(n_ego)
        o[:6] = offset
        # h = tanh(E_ego ego_x + b)
        self.w_h = (c["ego_w"] * s).contiguous()  # (d, 11)
        self.b_h = c["ego_b"] + c["ego_w"] @ o
        # W h_hat_j = Wc [nbr_x_j, rel_x_j] + bc, nbr_x_j = b_j * scale + offset, rel_x_j = (b_j - ego)[:3] / R_comm
        wc, bc = c["whh_w"], c["whh_b"]  # (d, 9), (d,)
        d = wc.shape[0]
        wrel = torch.zeros(d, 6)
        wrel[:, :3] = wc[:, 6:9] * r
        self.w_b_t = (wc[:, :6] * scale + wrel).t().contiguous()  # (6, d): belief -> W h_hat
        self.w_e = (-wrel).contiguous()  # (d, 6): ego -> W h_hat
        self.b_e = bc + wc[:, :6] @ offset
        self.a2 = c["a2"].contiguous()
        self.w_a1 = c["wa1"].contiguous()  # W^T a1
        # trunk: [h, m, ego_x] -> hidden
        t1 = c["t1_w"]
        s_t = torch.cat([torch.ones(2 * d), s])
        o_t = torch.cat([torch.zeros(2 * d), o])
        self.w_t1 = (t1 * s_t).contiguous()
        self.b_t1 = c["t1_b"] + t1 @ o_t
        self.w_t2, self.b_t2 = c["t2_w"].contiguous(), c["t2_b"].clone()
        self.w_mu, self.b_mu = c["mu_w"].contiguous(), c["mu_b"].clone()
        self.a_max_t = torch.tensor(self.a_max)
        self.one1, self.zero1 = torch.ones(1), torch.zeros(1)
        self.neg = torch.tensor(-1.0e9)
        self.zero = torch.tensor(0.0)

    def forward(
        self, ego: torch.Tensor, beliefs: torch.Tensor, mask: torch.Tensor, sense: torch.Tensor, fail_flag: torch.Tensor
    ) -> torch.Tensor:
        if ego.dim() != 1:
            return self.ref(ego, beliefs, mask, sense, fail_flag)
        x = torch.cat([ego, sense, torch.where(fail_flag, self.one1, self.zero1)])  # (11,) raw [ego, sense, f]
        h = torch.addmv(self.b_h, self.w_h, x).tanh_()
        whh = torch.addmm(torch.addmv(self.b_e, self.w_e, ego), beliefs, self.w_b_t)  # (M, d)
        e = torch.nn.functional.leaky_relu_(torch.addmv(torch.dot(h, self.w_a1), whh, self.a2), 0.2)
        alpha = torch.where(mask, torch.softmax(torch.where(mask, e, self.neg), -1), self.zero)
        m = torch.nn.functional.elu_(torch.mv(whh.t(), alpha))
        z = torch.addmv(self.b_t1, self.w_t1, torch.cat([h, m, x])).tanh_()
        z = torch.addmv(self.b_t2, self.w_t2, z).tanh_()
        return torch.addmv(self.b_mu, self.w_mu, z).tanh_().mul_(self.a_max_t)


def policy_constants(policy: DeployedPolicy) -> dict[str, torch.Tensor]:
    """The (unfused) constants FusedPolicy needs, from the eager module."""
    f = policy.actor.fusion
    w = f.W.weight
    with torch.no_grad():
        return {
            "ego_w": f.ego_enc.weight, "ego_b": f.ego_enc.bias,
            "whh_w": w @ torch.cat([f.encoder.weight, f.pe.weight], 1), "whh_b": w @ (f.encoder.bias + f.pe.bias),
            "a2": f.a2, "wa1": w.t() @ f.a1,
            "t1_w": policy.actor.trunk[0].weight, "t1_b": policy.actor.trunk[0].bias,
            "t2_w": policy.actor.trunk[2].weight, "t2_b": policy.actor.trunk[2].bias,
            "mu_w": policy.actor.mu.weight, "mu_b": policy.actor.mu.bias,
        }  # fmt: skip


def fuse_policy(policy: nn.Module) -> nn.Module:
    """The fused form of a DeployedPolicy; any other module is returned as it is."""
    if is_fused(policy) or not isinstance(policy, DeployedPolicy):
        return policy
    return FusedPolicy(policy.eval(), policy_constants(policy))


def fuse_tracker(tracker: BeliefTracker) -> nn.Module:
    """The fused tracker for phi (KinematicPredictor); other predictors are returned as they are."""
    p = getattr(tracker, "predictor", None)
    if is_fused(tracker) or not isinstance(tracker, BeliefTracker) or not isinstance(p, KinematicPredictor):
        return tracker
    with torch.no_grad():
        w1 = p.l1.weight @ p.T.t()
    return FusedKinematicTracker(tracker.eval(), w1, p.l1.bias, p.l2.weight, p.l2.bias, p.l3.weight, p.l3.bias, p.KG)


def _const_inputs(graph: torch._C.Graph, kind: str) -> list[list[torch.Tensor]]:
    """For every `kind` node of a frozen graph, in order, its constant tensor inputs."""
    out = []
    for node in graph.nodes():
        if node.kind() != kind:
            continue
        consts = [i.node().t("value") for i in node.inputs() if i.node().kind() == "prim::Constant" and i.type().kind() == "TensorType"]
        out.append(consts)
    return out


def fused_from_files(tracker: torch.jit.ScriptModule, policy: torch.jit.ScriptModule) -> tuple[nn.Module, nn.Module]:
    """Fused modules from already exported (frozen, unfused) predictor.pt / policy.pt.

    The frozen graphs hold the trained weights as constants (with the products the
    reference modules compute already folded); they are read back by the op that uses
    them, and the loaded modules stay inside as the reference for other batch shapes.
    A tracker that is not phi's (GRU, stale hold) is returned unchanged, as is a module
    that is already fused.
    """
    if not is_fused(policy):
        lin = [c for c in _const_inputs(policy.graph, "aten::linear") if len(c) == 2]
        vec = [c[0] for c in _const_inputs(policy.graph, "aten::matmul") if len(c) == 1]
        if len(lin) != 5 or len(vec) != 2:
            raise ValueError(f"policy graph is not the expected DeployedPolicy ({len(lin)} linear, {len(vec)} vector constants)")
        names = ["ego", "whh", "t1", "t2", "mu"]
        consts = {f"{n}_{k}": lin[i][j] for i, n in enumerate(names) for j, k in enumerate("wb")}
        consts["a2"], consts["wa1"] = vec
        policy = FusedPolicy(policy, consts)
    if not is_fused(tracker) and "aten::sigmoid" not in str(tracker.graph):  # a tanh-form phi (files before fused-v1)
        lin = [c for c in _const_inputs(tracker.graph, "aten::linear") if len(c) == 2]
        mat = [c[0] for c in _const_inputs(tracker.graph, "aten::matmul") if len(c) == 1]
        if len(lin) == 3 and len(mat) == 1 and tuple(mat[0].shape) == (9, 6):  # phi (KinematicPredictor)
            (w1, b1), (w2, b2), (w3, b3) = lin
            tracker = FusedKinematicTracker(tracker, w1, b1, w2, b2, w3, b3, mat[0])
    return tracker, policy


def refuse_directory(directory: str | Path) -> dict:
    """Re-export a shipped policy directory in the fused form, in place (same weights).

    The card keeps every field; `export` records the re-export and the previous files'
    sha256. Returns the new card.
    """
    from plmarl_sitl.learning.nn.io import export_policy, load_policy

    d = Path(directory)
    lp = load_policy(d)
    tracker, policy = fused_from_files(lp.tracker, lp.policy)
    if tracker is lp.tracker and policy is lp.policy:
        return lp.card  # nothing to fuse (already fused, or not a fusable form)
    card = {k: v for k, v in lp.card.items() if k not in ("card_version", "io", "sha256")}
    card["export"] = {
        "fused": {"predictor.pt": is_fused(tracker), "policy.pt": is_fused(policy)},
        "refused_from_sha256": dict(lp.card["sha256"]),
        "how": "python -m plmarl_sitl.learning.nn.deploy (weights read back from the frozen files; outputs equal to float32 rounding)",
    }
    export_policy(d, tracker, policy, card)
    return load_policy(d).card


if __name__ == "__main__":
    import sys

    for arg in sys.argv[1:]:
        c = refuse_directory(arg)
        print(arg, c["export"]["fused"], c["sha256"])
