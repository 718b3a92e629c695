"""Fused deployment forms of the PL-MARL tracker and policy (what `predictor.pt` and
`policy.pt` hold for phi's tracker and for an input-version-2 policy that takes the plan).

At these sizes (M <= 20 neighbours, K <= ~100 demand cells, 32-64 wide layers) a decision
costs the TorchScript interpreter's per-op overhead (~2-4 us an op on a slow core), not
FLOPs. The training modules (`BeliefTracker`, `KinematicPredictor`, `DeployedPolicy`) are
written for clarity and any batch shape; these modules compute the SAME function with fewer,
fused ops on the deployed agent's shapes and hand every other shape to the reference module
they wrap:

* every fixed linear map is folded into the next layer's weights at export: the feature
  normalisation (`build_policy_input`), the relative displacement (PE input), Encoder + PE
  + W of the attention, the token scaling, key and query of the demand attention, phi's
  input normalisation, and the point-mass integration (constant-velocity part) of phi's
  output;
* the policy's ego features enter the ego embedding and the trunk through one matrix each,
  from one raw vector [ego, target, sense, f, demand descriptor, plan offset near the point];
* the demand descriptor's bin (octant x range ring) is one affine map of [offset, offset^2]
  whose signs weigh into the bin number (no bucketize, no per-bit arithmetic);
* squared distances where only comparisons need them, and the demand tokens' tanh as the
  vectorised sigmoid (ATen's float tanh is scalar code);
* one agent runs on `addmv` / `addmm` with pre-transposed constant weights: one op per
  layer, bias included;
* the masked softmaxes compare against constant tensors (no scalar-to-tensor ops).

The folded constants are built from the eager module (`fuse_tracker`, `fuse_policy`) or
read back from an exported unfused file (`fused_policy_from_file`; `convert.py` re-exports a
policy directory that way). Outputs equal the reference module's: the tracker bit for bit,
the policy to float rounding (sums in another order, tanh as a sigmoid;
tests/learning/test_fused.py).
"""

from __future__ import annotations

from typing import Optional

import torch
from torch import nn
from torch.nn import functional as F

from plmarl_sitl.learning.nn.belief import MAX_AOI, NEVER, BeliefTracker, backfill
from plmarl_sitl.learning.nn.contract import PolicyForm
from plmarl_sitl.learning.nn.features import (
    DEMAND_BINS,
    DEMAND_RING_EDGES_M,
    DEMAND_SECTORS,
    EGO_FEATURES,
    PLAN_NEAR_M,
    map_blind_columns,
)
from plmarl_sitl.learning.nn.policy import DeployedPolicy
from plmarl_sitl.learning.nn.predictor import KinematicPredictor
from plmarl_sitl.model.coverage import SENSING_FEATURES

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


# The raw ego vector of the fused policy: [ego (6), target (2), sense, f (1), histogram, near (2)].
# The histogram has three columns per bin: all users, free users, and (unused, weight 0) the
# sum of the cells' nearer-neighbour counts, which rides along so that one log1p serves both.
_HIST_COLS = 3
_RAW_TARGET = 6
_RAW_SENSE = 8
_RAW_FAIL = _RAW_SENSE + SENSING_FEATURES
_RAW_DESC = _RAW_FAIL + 1
_RAW_NEAR = _RAW_DESC + _HIST_COLS * DEMAND_BINS
_RAW_FEATURES = _RAW_NEAR + 2


def _ego_feature_map(alt_max: float, v_max: float, r_comm: float, reads_map: bool = True) -> tuple[torch.Tensor, torch.Tensor]:
    """(S, o) with ego_x = S raw + o: `build_policy_input`'s ego features with a known plan.

    The raw descriptor is the fused histogram (bins, 3) flattened: [bin 0 all, bin 0 free,
    bin 0 unused, bin 1 all, ...]; ego_x has all users' bins, then the free users' bins.
    reads_map=False: the map-blind layout, raw [ego, target, sense, f, near] (no histogram)
    and ego_x without the descriptor (`features.map_blind_columns`)."""
    raw_near = _RAW_NEAR if reads_map else _RAW_DESC
    s, o = torch.zeros(EGO_FEATURES, raw_near + 2), torch.zeros(EGO_FEATURES)
    s[0, 2], o[0] = -2.0 / alt_max, -1.0  # altitude 0..alt_max -> [-1, 1] (z is down)
    for i in range(3):
        s[1 + i, 3 + i] = 1.0 / v_max
    for i in range(SENSING_FEATURES + 1):  # sensing, f: as they are
        s[4 + i, _RAW_SENSE + i] = 1.0
    desc = 4 + SENSING_FEATURES + 1
    if reads_map:
        for b in range(DEMAND_BINS):
            for k in range(2):
                s[desc + k * DEMAND_BINS + b, _RAW_DESC + _HIST_COLS * b + k] = 1.0
    plan = desc + 2 * DEMAND_BINS
    for i in range(2):
        s[plan + i, _RAW_TARGET + i], s[plan + i, i] = 1.0 / r_comm, -1.0 / r_comm  # (target - p) / R_comm
        s[plan + 2 + i, raw_near + i] = 1.0 / PLAN_NEAR_M  # clamp(target - p, +-PLAN_NEAR_M) / PLAN_NEAR_M
    o[plan + 4] = 1.0  # the plan is known
    if not reads_map:
        keep = map_blind_columns()
        s, o = s[keep], o[keep]
    return s, o


def _bin_map(edges: tuple[float, ...]) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The descriptor's bin as signs of an affine map of y = [dn, de, dn^2, de^2]:

    z = y P + c > 0 for [dn < 0, de < 0, |dn| < |de|, r^2 > edge_1^2, ...], and
    bin = z_bits . w = 4 [dn < 0] + 2 [de < 0] + [|dn| < |de|] + 8 ring
    (`features.demand_descriptor`'s octant and `bucketize` ring). The last column is r^2 itself.
    """
    n_z = 3 + len(edges) + 1
    proj, bias, w = torch.zeros(4, n_z), torch.zeros(n_z), torch.zeros(n_z, dtype=torch.long)
    proj[0, 0], proj[1, 1] = -1.0, -1.0
    proj[2, 2], proj[3, 2] = -1.0, 1.0  # de^2 - dn^2 > 0  <=>  |dn| < |de|
    w[0], w[1], w[2] = 4, 2, 1
    for j, r in enumerate(edges):
        proj[2, 3 + j], proj[3, 3 + j], bias[3 + j], w[3 + j] = 1.0, 1.0, -r * r, DEMAND_SECTORS
    proj[2, -1], proj[3, -1] = 1.0, 1.0
    return proj, bias, w


class _FusedActor(nn.Module):
    """What both fused policies share: the reference module, the file's attributes, and the
    folded ego embedding, neighbour attention and trunk.

    h = tanh(E_ego ego_x + b) and the trunk's ego_x part both read the raw vector (ego_x = S
    raw + o, `_ego_feature_map`); the trunk's first inputs are [h, m] (and md when the map is
    read). W h_hat_j = Wc [rel_p / R_comm, rel_v / V_max, rel_p / R_comm] + bc with rel =
    belief_j - ego, so one matrix applies to belief_j - ego. The helper methods are inlined
    by TorchScript: no call overhead at run time.
    """

    def __init__(self, ref: nn.Module, c: dict[str, torch.Tensor], reads_map: bool) -> None:
        super().__init__()
        self.ref = ref  # the reference DeployedPolicy (eager, or a loaded TorchScript file)
        self.deploy_form = DEPLOY_FORM
        self.alt_max, self.v_max, self.a_max = float(ref.alt_max), float(ref.v_max), float(ref.a_max)
        self.r_comm, self.claim_m, self.demand_unit = float(ref.r_comm), float(ref.claim_m), float(ref.demand_unit)
        self.input_version = int(ref.input_version)
        self.takes_plan = True
        self.reads_map = reads_map
        c = {k: v.detach().float() for k, v in c.items()}
        r, n_msg = self.r_comm, (3 if reads_map else 2) * c["ego_w"].shape[0]
        s, o = _ego_feature_map(self.alt_max, self.v_max, r, reads_map)
        t1, wc = c["t1_w"], c["whh_w"]
        self.w_h, self.b_h = (c["ego_w"] @ s).contiguous(), c["ego_b"] + c["ego_w"] @ o
        self.w_rel_t = torch.cat([(wc[:, 0:3] + wc[:, 6:9]) / r, wc[:, 3:6] / self.v_max], 1).t().contiguous()
        self.b_rel = c["whh_b"].clone()
        self.a2, self.w_a1 = c["a2"].contiguous(), c["wa1"].contiguous()
        self.w_t1, self.b_t1 = torch.cat([t1[:, :n_msg], t1[:, n_msg:] @ s], 1).contiguous(), c["t1_b"] + t1[:, n_msg:] @ o
        self.w_t2, self.b_t2 = c["t2_w"].contiguous(), c["t2_b"].clone()
        self.w_mu, self.b_mu = c["mu_w"].contiguous(), c["mu_b"].clone()
        self.near_m = PLAN_NEAR_M
        self.neg = torch.tensor(-1.0e9)
        self.zero = torch.tensor(0.0)
        self.a_max_t = torch.tensor(self.a_max)

    def _neighbour_message(self, h: torch.Tensor, ego: torch.Tensor, beliefs: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        whh = torch.addmm(self.b_rel, beliefs - ego, self.w_rel_t)  # (M, d) = W h_hat_j
        e = F.leaky_relu_(torch.addmv(torch.dot(h, self.w_a1), whh, self.a2), 0.2)
        alpha = torch.where(mask, torch.softmax(torch.where(mask, e, self.neg), 0), self.zero)
        return F.elu_(torch.mv(whh.t(), alpha))

    def _act(self, trunk_in: torch.Tensor) -> torch.Tensor:
        zt = torch.addmv(self.b_t1, self.w_t1, trunk_in).tanh_()
        zt = torch.addmv(self.b_t2, self.w_t2, zt).tanh_()
        return torch.addmv(self.b_mu, self.w_mu, zt).tanh_().mul_(self.a_max_t)


class FusedPolicy(_FusedActor):
    """`DeployedPolicy` (input version 2, with the plan) with its linear maps folded; same API.

    Fast path: one agent (ego (6,)) with M >= 1 neighbour slots, a demand map of K >= 1
    cells and a plan target. Other shapes and calls run `self.ref`.
    """

    def __init__(self, ref: nn.Module, c: dict[str, torch.Tensor]) -> None:
        super().__init__(ref, c, reads_map=True)
        c = {k: v.detach().float() for k, v in c.items()}
        d, r = c["ego_w"].shape[0], self.r_comm
        # demand tokens [dn, de, log1p(count / unit), clamp(nearest - own, +-2 R_comm), log1p(nearer)],
        # fed as [dn, de, log1p(count / unit), log1p(free, unused), log1p(nearer), clamp(nearest - own)]
        tw = c["tok_w"]
        self.w_tok_t = torch.stack([tw[:, 0] / r, tw[:, 1] / r, tw[:, 2], torch.zeros_like(tw[:, 2]), tw[:, 4],
                                    tw[:, 3] / r], 1).t().contiguous() * 2.0
        self.b_tok = c["tok_b"] * 2.0
        # v = tanh(a) = 2 sigmoid(2 a) - 1 = 2 s - 1 (ATen's float tanh is scalar code, sigmoid is
        # vectorised: 13 us against 1 us on K = 80 cells): the scores v . q = 2 s . q - sum(q) take
        # 2 q (a shift the softmax ignores), the pooled value beta . v = 2 beta . s - sum(beta).
        self.w_q = (c["key_w"].t() @ c["query_w"] * (2.0 / d**0.5)).contiguous()  # 2 q, q = K^T Q h / sqrt(d)
        proj, bias, w = _bin_map(DEMAND_RING_EDGES_M)
        self.bin_proj, self.bin_bias, self.bin_w = proj, bias, w
        self.n_bins = DEMAND_BINS
        self.far_sq = torch.tensor((4.0 * r) ** 2)  # demand_tokens: a masked neighbour is 4 R_comm away
        self.claim_sq = torch.tensor(self.claim_m**2)
        self.adv_max = 2.0 * r
        self.inv_unit = torch.tensor(1.0 / self.demand_unit)

    def forward(
        self,
        ego: torch.Tensor,
        beliefs: torch.Tensor,
        mask: torch.Tensor,
        sense: torch.Tensor,
        fail_flag: torch.Tensor,
        demand: Optional[torch.Tensor] = None,  # noqa: UP045 - TorchScript needs Optional
        target: Optional[torch.Tensor] = None,  # noqa: UP045
    ) -> torch.Tensor:
        if demand is None or target is None or ego.dim() != 1 or demand.size(0) == 0 or beliefs.size(0) == 0:
            return self.ref(ego, beliefs, mask, sense, fail_flag, demand, target)
        # Cells are rows (K, 1) where they meet the (K, M) neighbour distances: no unsqueeze.
        ego2 = ego.narrow(0, 0, 2)
        dem2 = demand.narrow(1, 0, 2)
        cu = demand.narrow(1, 2, 1).mul(self.inv_unit)  # (K, 1) users per unit
        dpos = dem2 - ego2  # (K, 2) cell offsets
        z = torch.addmm(self.bin_bias, torch.cat([dpos, dpos * dpos], 1), self.bin_proj)
        bins = z.gt(self.zero).mul(self.bin_w).sum(1)  # (K,) long: octant + 8 ring
        own_sq = z.narrow(1, 6, 1)  # (K, 1) the cell's squared ground distance
        diff = dem2.unsqueeze(1) - beliefs.narrow(1, 0, 2)
        diff = diff.mul_(diff)
        theirs_sq = diff.select(2, 0) + diff.select(2, 1)  # (K, M) squared (a sum over a size-2 dim is slow)
        nearest_sq = torch.where(mask, theirs_sq, self.far_sq).amin(1, keepdim=True)
        nearer = torch.lt(theirs_sq, own_sq).logical_and_(mask).sum(1, keepdim=True, dtype=torch.float32)
        # the descriptor: all users, and the users of cells no believed neighbour claims
        free = torch.where(nearest_sq <= self.claim_sq, self.zero, cu)
        x = torch.cat([cu, free, nearer], 1)  # (K, 3)
        hist = torch.zeros(self.n_bins, 3).index_add_(0, bins, x)
        near = torch.sub(target, ego2).clamp_(-self.near_m, self.near_m)
        raw = torch.cat([ego, target, sense, fail_flag.view(1), hist.view(-1).log1p_(), near])  # bool f: cat promotes
        h = torch.addmv(self.b_h, self.w_h, raw).tanh_()
        m = self._neighbour_message(h, ego, beliefs, mask)
        # demand attention over the cells
        adv = torch.sub(nearest_sq.sqrt_(), own_sq.sqrt()).clamp_(-self.adv_max, self.adv_max)
        s = torch.addmm(self.b_tok, torch.cat([dpos, x.log1p(), adv], 1), self.w_tok_t).sigmoid_()  # v = 2 s - 1
        live = cu.view(-1) > self.zero
        ed = torch.mv(s, torch.mv(self.w_q, h))
        beta = torch.where(live, torch.softmax(torch.where(live, ed, self.neg), 0), self.zero)
        md = F.elu_(torch.addmv(beta.sum().neg_(), s.t(), beta, alpha=2.0))
        return self._act(torch.cat([h, m, md, raw]))


class FusedPlanPolicy(_FusedActor):
    """A map-blind `DeployedPolicy` (`reads_map` False: no descriptor, no demand attention)
    with its linear maps folded; same API (`demand` is accepted and not read).

    Fast path: one agent (ego (6,)) with M >= 1 neighbour slots and a plan target, about 20
    ops. Other shapes and calls run `self.ref`.
    """

    def __init__(self, ref: nn.Module, c: dict[str, torch.Tensor]) -> None:
        super().__init__(ref, c, reads_map=False)

    def forward(
        self,
        ego: torch.Tensor,
        beliefs: torch.Tensor,
        mask: torch.Tensor,
        sense: torch.Tensor,
        fail_flag: torch.Tensor,
        demand: Optional[torch.Tensor] = None,  # noqa: UP045 - TorchScript needs Optional
        target: Optional[torch.Tensor] = None,  # noqa: UP045
    ) -> torch.Tensor:
        if target is None or ego.dim() != 1 or beliefs.size(0) == 0:
            return self.ref(ego, beliefs, mask, sense, fail_flag, demand, target)
        near = torch.sub(target, ego.narrow(0, 0, 2)).clamp_(-self.near_m, self.near_m)
        raw = torch.cat([ego, target, sense, fail_flag.view(1), near])  # bool f: cat promotes
        h = torch.addmv(self.b_h, self.w_h, raw).tanh_()
        return self._act(torch.cat([h, self._neighbour_message(h, ego, beliefs, mask), raw]))


def policy_constants(policy: DeployedPolicy) -> dict[str, torch.Tensor]:
    """The (unfused) constants the fused policies need, from the eager module (no tok_*, key,
    query for a map-blind actor)."""
    a = policy.actor
    f, dm = a.fusion, a.demand
    w = f.W.weight
    with torch.no_grad():
        c = {
            "ego_w": f.ego_enc.weight, "ego_b": f.ego_enc.bias,
            "whh_w": w @ torch.cat([f.encoder.weight, f.pe.weight], 1), "whh_b": w @ (f.encoder.bias + f.pe.bias),
            "a2": f.a2, "wa1": w.t() @ f.a1,
            "t1_w": a.trunk[0].weight, "t1_b": a.trunk[0].bias,
            "t2_w": a.trunk[2].weight, "t2_b": a.trunk[2].bias,
            "mu_w": a.mu.weight, "mu_b": a.mu.bias,
        }  # fmt: skip
        if dm is not None:
            c.update({"tok_w": dm.tok_enc.weight, "tok_b": dm.tok_enc.bias, "key_w": dm.key.weight,
                      "query_w": dm.query.weight})
        return c


def fuse_policy(policy: nn.Module) -> nn.Module:
    """The fused form of a DeployedPolicy that takes the plan; any other module is returned as it is."""
    if is_fused(policy) or not isinstance(policy, DeployedPolicy) or not policy.takes_plan:
        return policy
    fused = FusedPolicy if policy.reads_map else FusedPlanPolicy
    return fused(policy.eval(), policy_constants(policy))


def _const_inputs(graph: torch._C.Graph, kind: str) -> list[list[torch.Tensor]]:
    """For every `kind` node of a frozen graph (nested blocks included), in order, its constant tensor inputs."""
    out = []

    def walk(block) -> None:  # noqa: ANN001 - torch._C.Block
        for node in block.nodes():
            if node.kind() == kind:
                out.append([i.node().t("value") for i in node.inputs()
                            if i.node().kind() == "prim::Constant" and i.type().kind() == "TensorType"])
            for b in node.blocks():
                walk(b)

    walk(graph)
    return out


def fused_policy_from_file(policy: torch.jit.ScriptModule) -> nn.Module:
    """The fused form of an exported, frozen, unfused version-2 `policy.pt` that takes the plan.

    The frozen graph holds the trained weights as constants (with the products the reference
    module computes already folded); they are read back in the order `DeployedPolicy` uses
    them: ego_enc, W [Encoder | PE], a2, W^T a1, (tok_enc, key, query,) trunk 1, 2, mu. The
    loaded file stays inside as the reference for other shapes. Returns the file unchanged if
    it is already fused or does not take the plan; raises ValueError on another graph.
    """
    form = PolicyForm.of(policy)
    if is_fused(policy) or not form.takes_plan:
        return policy
    lin = _const_inputs(policy.graph, "aten::linear")
    vec = [c[0] for c in _const_inputs(policy.graph, "aten::matmul") if len(c) == 1]
    shapes = [len(c) for c in lin]
    with_map = form.reads_map
    expected = [2, 2, 2, 1, 1, 2, 2, 2] if with_map else [2, 2, 2, 2, 2]
    if shapes != expected or len(vec) != 2:
        raise ValueError(f"policy graph is not the expected DeployedPolicy (linear constants {shapes}, {len(vec)} vectors)")
    (ego_w, ego_b), (whh_w, whh_b), *demand, (t1_w, t1_b), (t2_w, t2_b), (mu_w, mu_b) = lin
    consts = {"ego_w": ego_w, "ego_b": ego_b, "whh_w": whh_w, "whh_b": whh_b, "a2": vec[0], "wa1": vec[1],
              "t1_w": t1_w, "t1_b": t1_b, "t2_w": t2_w, "t2_b": t2_b, "mu_w": mu_w, "mu_b": mu_b}
    if not with_map:
        return FusedPlanPolicy(policy, consts)
    (tok_w, tok_b), (key_w,), (query_w,) = demand
    consts.update({"tok_w": tok_w, "tok_b": tok_b, "key_w": key_w, "query_w": query_w})
    return FusedPolicy(policy, consts)
