"""What a survivor knows about failures, and how it spreads: per identity, its incarnation
and whether (and at which signalling instant) it was declared failed.

Why: a node failure is seen only by the failed UAV's neighbours (they miss its updates);
survivors out of its range would keep flying the old plan, and a plan re-solved from
different knowledge in different agents is no plan at all. So every signed state message
carries the sender's knowledge (docs/SIGNALLING.md, schema version 4, kind 'I').

A receiver merges what it hears per identity: the larger key 2 x incarnation + failed,
and of two declarations of one incarnation the earlier instant (one max of a rank per
entry, below). The merge is commutative, associative and idempotent, so knowledge reaches
every survivor the signalling graph connects, within one hop per signalling instant,
whatever the order of delivery, and agents that heard the same things hold the same
knowledge. The plan (`model/service.py::TeamPlans.settle`) is a function of the
declarations (identity, instant) and of common knowledge only.

A declaration is not for good (schema 4, session 14): after merging an instant's states,
every identity heard at that instant, and the receiver itself, is alive, so a declaration
of it gives way to its next incarnation (`alive_again`), which spreads and beats the
declaration everywhere. A UAV whose radio alone was cut across an instant, or a survivor
declared by a copy that mispredicted it, is taken back once heard; a dead UAV sends nothing.

A failure is declared by a neighbour from missed signalling instants: at each decision
while j has missed the `DECLARE_AFTER_MISSED` newest instants (1 since session 13; the
neighbour table still drops j from N_i after `drop_after_missed`), j is *suspected failed*
when it was predicted in clear hearing at each of them (`suspects`), or, heard at the
instant before, on a steady link (`steady`) or on a link predicted clear enough (`heard`): a
neighbour that flew out of range is predicted out of range and is not declared. And only when the plan that predicts j is the plan j flew (`may_predict`: j's
last message knew the receiver's declarations before that instant), and by a receiver that
still hears someone (an agent alone cannot tell a dead neighbour from its own isolation).
The twin holds every agent's knowledge in one `Gossip`; the deployed agent holds its own
(`model/knowledge.py::Knowledge`, `deploy/agent/plan.py`).
"""

from __future__ import annotations

import torch

from plmarl_sitl.mission import Channel
from plmarl_sitl.model.channel import db_to_lin, u2u_sinr
from plmarl_sitl.model.knowledge import NOTHING, Knowledge, Known

MAX_SWARM = 250  # identities a failed-set bitmask covers (the wire's 32-byte mask: ids 0..255)


# A silent neighbour is declared failed only where it should clearly be heard: predicted
# within this fraction of R_comm, with a predicted SINR this far above the threshold. The
# U2U links fail inside R_comm under interference (two UAVs on one cluster jam a third at
# 300 m), and a prediction is some metres off in transit; a false declaration lasts until the UAV is heard again.
SUSPECT_RANGE_FRAC = 0.8
SUSPECT_MARGIN_DB = 6.0
# Missed signalling instants in a row, each predicted in clear hearing, before a silent
# teammate is declared failed (session 13: was `drop_after_missed`, 2). The U2U channel is
# deterministic given positions, so a live teammate misses a clear-hearing instant only when
# it is far from where the plan-aware prediction puts it (>= ~70 m: 0.8 R_comm against
# R_comm, or the 6 dB margin) or its radio is cut (a `link_blackout` of it alone); measured
# false declarations: docs/RESULTS.md, session 13. One instant saves a whole T_up.
DECLARE_AFTER_MISSED = 1


def _links(predicted_pos: torch.Tensor, me: torch.Tensor, own_pos: torch.Tensor,
           channel: Channel) -> tuple[torch.Tensor, torch.Tensor]:
    """((..., A, M) predicted SINR of each link j -> a (linear; every identity transmits,
    failed ones included: interference is over-, never under-estimated), (..., A, M)
    squared distances), at predicted_pos (..., A, M, 3) with a's own row replaced by
    own_pos (..., A, 3); me (A,) each receiver's identity."""
    m = predicted_pos.shape[-2]
    own_row = torch.nn.functional.one_hot(me, m).bool().unsqueeze(-1)  # (A, M, 1)
    pos = torch.where(own_row, own_pos.unsqueeze(-2), predicted_pos)
    sinr = u2u_sinr(pos, torch.ones(pos.shape[:-1], dtype=torch.bool, device=pos.device), channel)  # [.., a, i, j]
    rows = me.view(*([1] * (pos.dim() - 3)), -1, 1, 1).expand(*pos.shape[:-3], -1, 1, m)
    sinr_a = torch.take_along_dim(sinr, rows, -2)[..., 0, :]  # (..., A, M): link j -> a
    d = pos - own_pos.unsqueeze(-2)
    return sinr_a, (d * d).sum(-1)


def _own_rows(pred: torch.Tensor, me: torch.Tensor) -> torch.Tensor:
    """(..., A, 3) each receiver's own row of the prediction pred (..., A, M, 3): its nominal."""
    idx = me.view(*([1] * (pred.dim() - 3)), -1, 1, 1).expand(*pred.shape[:-3], -1, 1, 3)
    return torch.take_along_dim(pred, idx, -2)[..., 0, :]


def suspects(dropped: torch.Tensor, predicted_pos: torch.Tensor, me: torch.Tensor, own_pos: torch.Tensor,
             channel: Channel, comm_m: float) -> torch.Tensor:
    """(..., A, M) bool: receiver a's dropped neighbours (dropped (..., A, M)) that it should
    hear: at the positions it predicts for the team (predicted_pos (..., A, M, 3), its own
    row replaced by own_pos (..., A, 3); me (A,) its identity) the shared channel model gives
    the link j -> a a clear margin (`SUSPECT_RANGE_FRAC`, `SUSPECT_MARGIN_DB`)."""
    return dropped & clear_hearing(predicted_pos, me, own_pos, channel, comm_m)


def clear_hearing(predicted_pos: torch.Tensor, me: torch.Tensor, own_pos: torch.Tensor,
                  channel: Channel, comm_m: float) -> torch.Tensor:
    """(..., A, M) bool: the links j -> a with the clear margin of `suspects`, for every j
    (a function of the predicted positions alone: a deployed agent keeps it while they do)."""
    sinr_a, d2 = _links(predicted_pos, me, own_pos, channel)
    near = d2 <= (SUSPECT_RANGE_FRAC * comm_m) ** 2
    clear = sinr_a >= db_to_lin(channel.sinr_threshold_db + SUSPECT_MARGIN_DB)
    return near & clear


# A link heard at the previous instant is "steady" at the missed one when the prediction
# moved neither end by more than STEADY_MOVE_M, keeps it STEADY_RANGE_M inside R_comm, and
# gives it at most STEADY_DROP_DB less SINR than then and at least STEADY_MARGIN_DB above the threshold. The
# U2U channel is a deterministic function of the positions (free space, mean interference),
# so a live teammate on a steady link is heard again unless the positions are off the
# prediction; this covers teammates too far for clear hearing (a cluster's pair dying
# together, heard only by UAVs 250-330 m away).
STEADY_MOVE_M = 10.0
STEADY_RANGE_M = 20.0
STEADY_MARGIN_DB = 1.0
STEADY_DROP_DB = 0.5


def steady(heard_prev: torch.Tensor, pred_now: torch.Tensor, pred_prev: torch.Tensor, me: torch.Tensor,
           channel: Channel, comm_m: float) -> torch.Tensor:
    """(..., A, M) bool: receiver a's teammates heard at the previous instant (heard_prev
    (..., A, M)) whose link j -> a is steady at the missed instant: the predictions
    pred_now / pred_prev (..., A, M, 3) at the two instants (a's own row its own nominal)."""
    return heard_prev & steady_links(pred_now, pred_prev, me, channel, comm_m)


def steady_links(pred_now: torch.Tensor, pred_prev: torch.Tensor, me: torch.Tensor,
                 channel: Channel, comm_m: float) -> torch.Tensor:
    """(..., A, M) bool: the links j -> a `steady` finds steady, for every j (a function of the
    two predictions alone)."""
    own_now, own_prev = _own_rows(pred_now, me), _own_rows(pred_prev, me)
    s_now, d2 = _links(pred_now, me, own_now, channel)
    s_prev, _ = _links(pred_prev, me, own_prev, channel)
    moved = ((pred_now - pred_prev) ** 2).sum(-1) <= STEADY_MOVE_M ** 2  # (..., A, M)
    self_moved = ((own_now - own_prev) ** 2).sum(-1, keepdim=True) <= STEADY_MOVE_M ** 2
    ok = (s_now >= s_prev * db_to_lin(-STEADY_DROP_DB)) & (s_now >= db_to_lin(channel.sinr_threshold_db + STEADY_MARGIN_DB))
    return moved & self_moved & ok & (d2 <= (comm_m - STEADY_RANGE_M) ** 2)


# A link heard at the previous instant is also evidence when the prediction at the missed
# instant keeps it HEARD_RANGE_M inside R_comm and HEARD_MARGIN_DB above the SINR threshold,
# however far its ends moved (`steady` asks for <= STEADY_MOVE_M): the channel is a function of
# the positions, and the plan-aware prediction puts a teammate flying its plan where it is. Clear
# hearing's 6 dB alone left failures nobody declared: a survivor that heard the failed UAV at
# 180-215 m, predicted 4.5-5.9 dB above the threshold after both had moved (docs/RESULTS.md,
# session 26). The link was heard at the previous instant, so the interference a predicted
# margin leaves out (a teammate off its point) was already below it then.
HEARD_RANGE_M = 20.0
HEARD_MARGIN_DB = 3.0


def heard(heard_prev: torch.Tensor, pred_now: torch.Tensor, me: torch.Tensor, channel: Channel,
          comm_m: float) -> torch.Tensor:
    """(..., A, M) bool: receiver a's teammates heard at the previous instant (heard_prev
    (..., A, M)) whose link j -> a the prediction at the missed instant keeps clear enough
    (`heard_links`)."""
    return heard_prev & heard_links(pred_now, me, channel, comm_m)


def heard_links(pred_now: torch.Tensor, me: torch.Tensor, channel: Channel, comm_m: float) -> torch.Tensor:
    """(..., A, M) bool: the links j -> a the prediction pred_now (..., A, M, 3) (a's own row its
    own nominal) keeps HEARD_RANGE_M inside R_comm and HEARD_MARGIN_DB above the SINR threshold
    (a function of the prediction alone)."""
    sinr_a, d2 = _links(pred_now, me, _own_rows(pred_now, me), channel)
    return (d2 <= (comm_m - HEARD_RANGE_M) ** 2) & (sinr_a >= db_to_lin(channel.sinr_threshold_db + HEARD_MARGIN_DB))


# A knowledge entry, one int per (knower, identity): the rank 2^32 x key + (2^32 - 1 - since),
# key = 2 x incarnation + (1 if declared failed), since = the signalling instant the
# declaration names (0 when not failed). The merge is the max of ranks: a newer incarnation
# beats any declaration of an older one, at one incarnation "failed" beats "alive", and of
# two declarations of the same incarnation the earlier instant wins. A max is commutative,
# associative and idempotent, so knowledge converges whatever the order of delivery.
SINCE_MASK = (1 << 32) - 1


def rank_of(key: torch.Tensor, since: torch.Tensor) -> torch.Tensor:
    return (key << 32) | (SINCE_MASK - since)


def key_of(rank: torch.Tensor) -> torch.Tensor:
    """2 x incarnation + (1 if declared failed)."""
    return rank >> 32


def since_of(rank: torch.Tensor) -> torch.Tensor:
    """The instant a failed identity was declared at (0 for one not failed)."""
    return SINCE_MASK - (rank & SINCE_MASK)


def may_predict(heard_rank: torch.Tensor, rank: torch.Tensor, newest_instant: int) -> torch.Tensor:
    """(..., M) bool: the receiver's plan-aware prediction of each neighbour is the plan the
    neighbour flew at the instants it missed (up to `newest_instant`). A plan is a function
    of the declarations (identity, instant) alone (`TeamPlans.settle`), and a declaration
    at instant s changes the prediction only after s; so the neighbour's last message
    (heard_rank (..., M, N)) and the receiver's knowledge (rank (..., N)) must differ only
    in declarations not before the newest instant."""
    hf, f = key_of(heard_rank) % 2 == 1, (key_of(rank) % 2 == 1).unsqueeze(-2)
    hs, s = since_of(heard_rank), since_of(rank).unsqueeze(-2)
    differ = (hf != f) | (hf & f & (hs != s))
    early = (hf & (hs < newest_instant)) | (f & (s < newest_instant))
    return ~(differ & early).any(-1)


def alive_again(rank: torch.Tensor, heard: torch.Tensor) -> torch.Tensor:
    """The refutation rule, after the merge of a signalling instant: an identity heard then
    (heard (..., N): a message of it arrived, or it is the receiver itself) is alive, so a
    declaration of it (an odd key) gives way to the next incarnation, alive. Every merged
    declaration was made at a decision before the instant (a decision follows its instant's
    messages), so the message proves life after it."""
    key = key_of(rank)
    refuted = heard & (key % 2 == 1)
    return torch.where(refuted, rank_of(key + 1, torch.zeros_like(key)), rank)


class Gossip:
    """Every twin agent's knowledge, (B, N, N) rank [i, j] (what i knows of j, above),
    exchanged at the signalling instants with the states.

    A controller adds its agents' own declarations (`declare`) at its decisions; at the
    next signalling instant each live agent's knowledge goes out with its state, and each
    receiver merges what it got and applies the refutation rule (`receive`), as the
    deployed agent's `Knowledge` does with the knowledge of each state message it accepts.
    `sent` keeps what went out at the last instant (the knowledge field of each sender's
    state message)."""

    def __init__(self, batch: int, n: int, device: str = "cpu") -> None:
        self.rank = rank_of(torch.zeros(batch, n, n, dtype=torch.int64, device=device), torch.zeros(batch, n, n, dtype=torch.int64, device=device))
        self.sent = self.rank.clone()
        self.heard_rank = self.rank.unsqueeze(-2).repeat(1, 1, n, 1)  # [i, j]: the knowledge j's last message to i carried

    @property
    def key(self) -> torch.Tensor:
        return key_of(self.rank)

    @property
    def failed(self) -> torch.Tensor:
        """(B, N, N) bool [i, j]: i knows j failed (at j's newest incarnation i knows)."""
        return self.key % 2 == 1

    @property
    def since(self) -> torch.Tensor:
        """(B, N, N) [i, j]: the instant of the declaration of j that i knows (0: not failed)."""
        return since_of(self.rank)

    @property
    def epoch(self) -> torch.Tensor:
        """(B, N) each agent's plan epoch: its newest declaration's instant (0: none)."""
        return self.since.amax(-1)

    def declare(self, failed: torch.Tensor, epoch: torch.Tensor) -> None:
        """Agents' own findings: failed (B, N, N) [i, j] i declares j failed at its epoch (B, N)."""
        key = self.key
        new = failed & (key % 2 == 0)
        self.rank = torch.where(new, rank_of(key + 1, epoch.unsqueeze(-1).expand_as(key)), self.rank)

    def receive(self, got: torch.Tensor) -> None:
        """A signalling instant: got (B, N, N) bool [i, j], i received j's state message now.
        Everyone sends the knowledge it held before the instant (the broadcast is simultaneous)."""
        self.sent = self.rank.clone()
        self.heard_rank = torch.where(got.unsqueeze(-1), self.rank.unsqueeze(-3), self.heard_rank)
        heard = torch.where(got.unsqueeze(-1), self.rank.unsqueeze(-3), torch.zeros_like(self.rank).unsqueeze(-3)).amax(-2)
        itself = torch.eye(got.shape[-1], dtype=torch.bool, device=got.device)
        self.rank = alive_again(torch.maximum(self.rank, heard), got | itself)


__all__ = ["DECLARE_AFTER_MISSED", "HEARD_MARGIN_DB", "HEARD_RANGE_M", "MAX_SWARM", "NOTHING", "STEADY_MARGIN_DB", "STEADY_MOVE_M", "STEADY_RANGE_M",
           "SUSPECT_MARGIN_DB", "SUSPECT_RANGE_FRAC", "Gossip", "clear_hearing", "heard", "heard_links", "steady_links", "Known", "Knowledge", "SINCE_MASK", "alive_again", "key_of", "rank_of", "since_of", "may_predict",
           "steady", "suspects"]
