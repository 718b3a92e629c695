"""One deployed agent's knowledge of failures, as plain ints (the wire's form, no torch):
the failed set, the plan epoch and the identities' incarnations (model/gossip.py has the
rules and the twin's batched form; this module applies the same rules to one agent)."""

from __future__ import annotations


def _key(failed: int, inc: dict[int, int], j: int) -> int:
    return 2 * inc.get(j, 0) + (failed >> j & 1)


class Known:
    """One agent's knowledge as a value (the wire's form): the failed set (bitmask), the
    plan epoch, and the identities' incarnations (identity -> incarnation, only those > 0).
    Merged per identity by `key_of` and refuted by `alive_again`'s rule, on ints."""

    __slots__ = ("epoch", "failed", "inc")

    def __init__(self, failed: int = 0, epoch: int = 0, inc: dict[int, int] | None = None) -> None:
        self.failed, self.epoch = int(failed), int(epoch)
        self.inc = {j: c for j, c in (inc or {}).items() if c > 0}

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Known) and (self.failed, self.epoch, self.inc) == (other.failed, other.epoch, other.inc)

    def __repr__(self) -> str:
        return f"Known(failed={self.failed:#x}, epoch={self.epoch}, inc={self.inc})"

    def key(self, j: int) -> int:
        return _key(self.failed, self.inc, j)

    def ids(self) -> set[int]:
        """Identities with anything known (failed or a newer incarnation)."""
        out = set(self.inc)
        f, j = self.failed, 0
        while f:
            if f & 1:
                out.add(j)
            f, j = f >> 1, j + 1
        return out

    def merged(self, other: Known) -> Known:
        failed, inc = 0, {}
        for j in self.ids() | other.ids():
            k = max(self.key(j), other.key(j))
            failed |= (k & 1) << j
            inc[j] = k >> 1
        return Known(failed, max(self.epoch, other.epoch), inc)

    def refuted(self, heard: list[int] | set[int], t: int) -> Known:
        """`alive_again` on this knowledge: the identities heard at instant t are alive."""
        back = [j for j in heard if self.failed >> j & 1]
        if not back:
            return self
        inc = dict(self.inc)
        failed = self.failed
        for j in back:
            inc[j] = inc.get(j, 0) + 1
            failed &= ~(1 << j)
        return Known(failed, max(self.epoch, t), inc)

    def extends(self, other: Known) -> bool:
        """model/gossip.py::extends for every identity: this is other's knowledge grown,
        never a declaration other knew refuted."""
        return all(self.key(j) >= other.key(j) and (other.key(j) % 2 == 0 or self.key(j) == other.key(j)) for j in other.ids())


NOTHING = Known()


class Knowledge:
    """One deployed agent's knowledge, with the second each piece arrived at: its state
    message for instant k carries what the twin's does, everything learnt before k (the
    twin's agents send at the instant what they knew before it), and its decision at k
    uses everything learnt up to k. At each second, in order, what arrived then is merged
    and then the identities heard then (and the agent itself) refute their declarations,
    as the twin's `Gossip.receive` does at the instant."""

    def __init__(self, me: int) -> None:
        self.me = me
        self.parts: dict[float, Known] = {}  # second learnt -> knowledge merged, non-empty only
        self.heard_at: dict[float, set[int]] = {}  # second -> senders whose state of that instant arrived
        self.heard: dict[int, Known] = {}  # sender -> the knowledge its last message carried

    def learn(self, t: float, known: Known, sender: int | None = None) -> None:
        if sender is not None:
            self.heard[sender] = known
            self.heard_at.setdefault(t, set()).add(sender)
        if known.failed or known.epoch or known.inc:  # one entry per second: at most one per signalling instant and decision
            self.parts[t] = self.parts.get(t, NOTHING).merged(known)

    def view(self, before: float) -> Known:
        """The knowledge of everything learnt before second `before`."""
        out = NOTHING
        for t in sorted(set(self.parts) | set(self.heard_at)):
            if t >= before:
                break
            if t in self.parts:
                out = out.merged(self.parts[t])
            out = out.refuted(self.heard_at.get(t, set()) | {self.me}, int(t))
        return out


__all__ = ["NOTHING", "Known", "Knowledge"]
