"""One deployed agent's knowledge of failures, as plain ints (the wire's form, no torch):
per identity its incarnation and, if declared failed, the signalling instant the
declaration names. model/gossip.py has the rules and the twin's batched form (one rank
per entry); this module applies the same rules to one agent."""

from __future__ import annotations

import bisect


class Known:
    """One agent's knowledge as a value: `failed` identity -> the instant it was declared
    at, `inc` identity -> incarnation (only those > 0). Per identity the merge keeps the
    larger key (2 x incarnation + failed), and of equal keys the earlier instant, as the
    twin's max of ranks (model/gossip.py)."""

    __slots__ = ("failed", "inc")

    def __init__(self, failed: dict[int, int] | None = None, inc: dict[int, int] | None = None) -> None:
        self.failed = dict(failed or {})
        self.inc = {j: c for j, c in (inc or {}).items() if c > 0}

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Known) and (self.failed, self.inc) == (other.failed, other.inc)

    def __repr__(self) -> str:
        return f"Known(failed={self.failed}, inc={self.inc})"

    @property
    def epoch(self) -> int:
        """The plan epoch: the newest declaration's instant (0: none)."""
        return max(self.failed.values(), default=0)

    @property
    def mask(self) -> int:
        """The failed set as a bitmask (bit j = identity j)."""
        return sum(1 << j for j in self.failed)

    def key(self, j: int) -> int:
        return 2 * self.inc.get(j, 0) + (j in self.failed)

    def entry(self, j: int) -> tuple[int, int]:
        """(key, -instant): larger wins the merge."""
        return self.key(j), -self.failed.get(j, 0)

    def merged(self, other: Known) -> Known:
        if not other.failed and not other.inc:
            return self
        failed, inc = {}, {}
        for j in set(self.failed) | set(self.inc) | set(other.failed) | set(other.inc):
            key, neg = max(self.entry(j), other.entry(j))
            inc[j] = key >> 1
            if key & 1:
                failed[j] = -neg
        return Known(failed, inc)

    def declared(self, ids: list[int], at: int) -> Known:
        """This knowledge with identities `ids` (not failed here) declared failed at instant `at`."""
        return Known(self.failed | {j: at for j in ids if j not in self.failed}, self.inc)

    def refuted(self, heard: set[int]) -> Known:
        """model/gossip.py::alive_again: the identities heard at an instant are alive."""
        back = [j for j in heard if j in self.failed]
        if not back:
            return self
        return Known({j: s for j, s in self.failed.items() if j not in back},
                     self.inc | {j: self.inc.get(j, 0) + 1 for j in back})

    def predicts_alike(self, heard: Known, newest: int) -> bool:
        """model/gossip.py::may_predict: the two differ only in declarations not before `newest`."""
        for j in set(self.failed) | set(heard.failed):
            s, hs = self.failed.get(j), heard.failed.get(j)
            if s != hs and ((s is not None and s < newest) or (hs is not None and hs < newest)):
                return False
        return True


NOTHING = Known()


class Knowledge:
    """One deployed agent's knowledge, with the second each piece arrived at: its state
    message for instant k carries what the twin's does, everything learnt before k (the
    twin's agents send at the instant what they knew before it), and its decision at k
    uses everything learnt up to k. At each second, in order, what arrived then is merged
    and then the identities heard then (and the agent itself) refute their declarations,
    as the twin's `Gossip.receive` does at the instant. The fold is kept per second and
    recomputed only from the earliest second something new arrived at (a decision reads
    it two or three times; folding a whole mission each time cost ~ms at N = 20)."""

    def __init__(self, me: int) -> None:
        self.me = me
        self.parts: dict[float, Known] = {}  # second learnt -> knowledge merged, non-empty only
        self.heard_at: dict[float, set[int]] = {}  # second -> senders whose state of that instant arrived
        self.heard: dict[int, Known] = {}  # sender -> the knowledge its last message carried
        self.times: list[float] = []  # every second in parts or heard_at, ascending
        self.folded: list[Known] = []  # folded[i]: the knowledge after times[i]; valid for i < len(folded)

    def learn(self, t: float, known: Known, sender: int | None = None) -> None:
        changed = False
        if sender is not None:
            self.heard[sender] = known
            at = self.heard_at.setdefault(t, set())
            changed = sender not in at
            at.add(sender)
        if known.failed or known.inc:  # one entry per second: at most one per signalling instant and decision
            self.parts[t] = self.parts.get(t, NOTHING).merged(known)
            changed = True
        if changed:
            i = bisect.bisect_left(self.times, t)
            if i == len(self.times) or self.times[i] != t:
                self.times.insert(i, t)
            del self.folded[i:]

    def view(self, before: float) -> Known:
        """The knowledge of everything learnt before second `before`."""
        upto = bisect.bisect_left(self.times, before)
        while len(self.folded) < upto:
            t = self.times[len(self.folded)]
            out = self.folded[-1] if self.folded else NOTHING
            if t in self.parts:
                out = out.merged(self.parts[t])
            self.folded.append(out.refuted(self.heard_at.get(t, set()) | {self.me}))
        return self.folded[upto - 1] if upto else NOTHING


__all__ = ["NOTHING", "Known", "Knowledge"]
