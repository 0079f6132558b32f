"""How the robot orders the samples of one stream (a sensor source, a remote behaviour's votes).

Stamps alone cannot order samples: one sample stamped far in the future would stay "newest"
for ever and pin the stream. So the robot checks two things, in this order:

1. **Not from the future.** A sample stamped more than a small tolerance ahead of the robot
   clock is refused (:func:`ahead_of_clock`). The tolerance covers devices in other
   processes that follow simulated time and saw a clock sample a little before the robot
   did.
2. **Newer from its publisher** (:class:`SampleOrder`). A sample carrying a publisher
   identity ``pub`` (``ubf_async`` publishers always send one, new for every publisher
   instance) is accepted when that publisher is new to the stream or its ``seq`` is higher
   than the last one accepted from it: a restarted component is a new publisher and is
   accepted at once, a replayed or reordered sample is refused. A client that sends no
   ``pub`` (a plain msgpack client written from docs/protocol.md) is ordered by ``seq``,
   and a sample whose ``seq`` is not higher but whose stamp is newer than the last one
   accepted from such clients is taken as a restart and accepted.

The stream remembers the last ``seq`` of at most ``max_publishers`` publishers (the least
recently accepted is forgotten first); a forgotten publisher that speaks again counts as new.
Who may publish at all is not decided here: that is zenoh's access control (secure mode).
"""

from __future__ import annotations

import enum
from collections import OrderedDict

__all__ = ["Refusal", "SampleOrder", "ahead_of_clock"]


class Refusal(enum.StrEnum):
    """Why a valid sample was not taken (the counters' keys)."""

    FUTURE = "future"
    """Stamped ahead of the robot clock by more than the tolerance."""
    OUT_OF_ORDER = "out_of_order"
    """Not newer than what its publisher already sent (a replay, or reordered)."""
    NAME_TOO_LONG = "name_too_long"
    """A source name longer than :data:`~ubf_async.wire.topics.MAX_NAME_CHARS`."""
    FULL = "full"
    """No room for a new source: every source held is protected, or has sent at least as
    many samples lately as the newcomer."""


def ahead_of_clock(stamp_ns: int, now_ns: int, tolerance_ns: int) -> bool:
    """Whether ``stamp_ns`` lies more than ``tolerance_ns`` ahead of the robot clock."""
    return stamp_ns - now_ns > tolerance_ns


class SampleOrder:
    """The ordering rule of one stream (module docstring). Not thread-safe: use on the loop."""

    __slots__ = ("_plain", "_seqs", "max_publishers")

    def __init__(self, *, max_publishers: int = 8) -> None:
        if max_publishers < 1:
            raise ValueError(f"max_publishers must be ≥ 1, got {max_publishers}")
        self.max_publishers = max_publishers
        self._seqs: OrderedDict[int, int] = OrderedDict()
        """Last accepted seq per publisher identity, least recently accepted first."""
        self._plain: tuple[int, int] | None = None
        """(seq, stamp_ns) of the last sample accepted from clients without ``pub``."""

    def admits(self, *, pub: int | None, seq: int, stamp_ns: int) -> bool:
        """Whether the sample is newer from its publisher; records nothing."""
        if pub is None:
            last = self._plain
            return last is None or seq > last[0] or stamp_ns > last[1]
        last_seq = self._seqs.get(pub)
        return last_seq is None or seq > last_seq

    def accept(self, *, pub: int | None, seq: int, stamp_ns: int) -> bool:
        """:meth:`admits`, and if so remember the sample as its publisher's newest."""
        if not self.admits(pub=pub, seq=seq, stamp_ns=stamp_ns):
            return False
        if pub is None:
            self._plain = (seq, stamp_ns)
            return True
        seqs = self._seqs
        seqs[pub] = seq
        seqs.move_to_end(pub)
        if len(seqs) > self.max_publishers:
            seqs.popitem(last=False)
        return True

    def publishers(self) -> int:
        """How many publishers (with ``pub``) the stream remembers."""
        return len(self._seqs)

    def clear(self) -> None:
        """Forget everything (a new run)."""
        self._seqs.clear()
        self._plain = None
