"""Refusal notices: a process whose samples or votes the robot refuses hears why, at once.

The robot refuses a sensor sample or a remote behaviour's vote for reasons its sender can do
something about — stamped ahead of the robot clock (usually: stamped on the wrong clock), out
of order, malformed, no place for it in the tree. It counts and logs each refusal on its own
console (:mod:`ubf_async.runtime.aggregator`, :mod:`ubf_async.services.remote`), which the sender's
user does not see. So the robot also publishes a **notice** on ``ubf/<robot>/refused/<key>``, where
``<key>`` is the refused sample's key under ``ubf/<robot>/`` — ``refused/sensor/range/left``,
``refused/vote/seek_pink_ball/teleop`` — saying why in a word (``reason``), in the sentence it
logged (``detail``), and how many of that key's it has refused so far (``count``): schema
``refusal``, ``docs/protocol.md``.

Bounded, so a flood of bad samples cannot become a flood of notices
(:class:`RefusalNotices`): per key the first refusal is noticed at once, later ones at most
once per :data:`NOTICE_PERIOD_S` (with the count so far); at most :data:`MAX_NOTICES_PER_S`
notices a second in all; :data:`MAX_KEYS` keys remembered, the least recently refused
forgotten first.

A notice is a best-effort sample, and the first one of a key usually goes out just as its
sender joins the network — when zenoh is still linking the newcomer's peers and can lose it.
So each notice is sent once more :data:`NOTICE_PERIOD_S` later, with the count by then: a
refusal that happened once is still heard. A receiver takes a count it has already had for
that key as the same notice (:class:`RefusalWatch` says it once).

The sender's side (:class:`RefusalWatch`) subscribes to ``ubf/<robot>/refused/**`` and says,
on its own console, what the robot refuses of what this process publishes: every standalone
device (``python -m components.<device>``) and remote behaviour does.
"""

from __future__ import annotations

import asyncio
import logging
import sys
import time
import weakref
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass

from ubf_async.errors import ProtocolError
from ubf_async.runtime.bus import Bus, Publisher, Subscription
from ubf_async.runtime.ratelimit import TokenBucket
from ubf_async.wire.protocol import clip, decode_or_count
from ubf_async.wire.topics import MAX_REFUSAL_DETAIL, REFUSED, RefusalNotice

__all__ = ["MAX_KEYS", "MAX_NOTICES_PER_S", "NOTICE_PERIOD_S", "RefusalNotices", "RefusalWatch",
           "notices_of"]

log = logging.getLogger(__name__)

NOTICE_PERIOD_S = 1.0
"""Per key: after its first notice, at most one notice per this many seconds (wall time)."""
MAX_NOTICES_PER_S = 20.0
"""Notices per second in all (a burst of as many is allowed)."""
MAX_KEYS = 256
"""Keys whose refusals are remembered (their counts and publishers)."""


@dataclass(slots=True)
class _Refused:
    count: int
    noticed_ns: int | None
    """Wall time (``CLOCK_MONOTONIC``) of its last notice; ``None`` before the first."""
    publisher: Publisher | None
    noticed_count: int = 0
    """The count its last notice carried."""
    again: asyncio.TimerHandle | None = None
    """Its last notice, due to be sent once more (module docstring)."""


class RefusalNotices:
    """The robot's side: :meth:`report` each refusal; notices go out within the bounds of
    the module docstring. Use it on the bus's event loop (where samples are ingested)."""

    def __init__(self, bus: Bus, *, period_s: float = NOTICE_PERIOD_S,
                 max_per_s: float = MAX_NOTICES_PER_S, max_keys: int = MAX_KEYS,
                 wall_ns: Callable[[], int] = time.monotonic_ns) -> None:
        if not (period_s >= 0 and max_per_s > 0 and max_keys >= 1):
            raise ValueError("need period_s ≥ 0, max_per_s > 0 and max_keys ≥ 1")
        self.bus = bus
        self.period_ns = round(period_s * 1e9)
        self.max_per_s = max_per_s
        self.max_keys = max_keys
        self.wall_ns = wall_ns
        self._refused: OrderedDict[str, _Refused] = OrderedDict()
        self._bucket = TokenBucket(rate_hz=max_per_s, burst=max(1, round(max_per_s)),
                                   now_ns=wall_ns())
        self.sent = 0
        """Notices published."""
        self.held_back = 0
        """Notices not published for the overall rate bound."""

    def report(self, key: str, reason: str, detail: str) -> None:
        """Count one refusal of a sample or vote on ``key`` (a concrete key of this robot) and
        publish a notice if the bounds allow. A key that is not ``sensor/<kind>/<name>`` or
        ``vote/<composite>/<behaviour>`` (a malformed vote key) gets none."""
        head = f"{self.bus.keys.prefix}/"
        parts = key[len(head):].split("/") if key.startswith(head) else []
        if len(parts) != 3 or parts[0] not in ("sensor", "vote") or not all(parts):
            return
        refused = self._refused.get(key)
        if refused is None:
            refused = self._refused[key] = _Refused(0, None, None)
            if len(self._refused) > self.max_keys:
                _, gone = self._refused.popitem(last=False)
                if gone.again is not None:
                    gone.again.cancel()
                if gone.publisher is not None:
                    gone.publisher.close()
        else:
            self._refused.move_to_end(key)
        refused.count += 1
        now = self.wall_ns()
        if refused.noticed_ns is not None and now - refused.noticed_ns < self.period_ns:
            return
        self._notice(key, parts, refused, RefusalNotice(
            reason=clip(reason, 128), detail=clip(detail, MAX_REFUSAL_DETAIL),
            count=refused.count))

    def _notice(self, key: str, parts: list[str], refused: _Refused,
                notice: RefusalNotice) -> None:
        """Publish ``notice`` if the overall bound allows, and have it sent once more a
        period later (with the count by then) unless it is that repetition of an unchanged
        count already."""
        now = self.wall_ns()
        if not self._bucket.take(now):
            self.held_back += 1
            return
        try:
            if refused.publisher is None:
                refused.publisher = self.bus.publisher(REFUSED, *parts)
            refused.publisher.publish(notice)
        except (ProtocolError, ValueError) as exc:  # a name zenoh or the schema cannot carry
            log.debug("no refusal notice for %s: %s", clip(key), exc)
            return
        repeated = notice.count == refused.noticed_count
        refused.noticed_ns, refused.noticed_count = now, notice.count
        self.sent += 1
        if refused.again is not None:
            refused.again.cancel()
            refused.again = None
        if repeated:
            return
        try:
            loop = asyncio.get_running_loop()
        except RuntimeError:  # a caller off the loop (a synchronous test): nothing to repeat on
            return
        refused.again = loop.call_later(self.period_ns / 1e9, self._again, key, parts,
                                        refused, notice)

    def _again(self, key: str, parts: list[str], refused: _Refused,
               notice: RefusalNotice) -> None:
        refused.again = None
        if self.bus.closed or self._refused.get(key) is not refused:
            return  # the robot has ended, or the key was forgotten
        self._notice(key, parts, refused, RefusalNotice(
            reason=notice.reason, detail=notice.detail, count=refused.count))

    def count(self, key: str) -> int:
        """Refusals of ``key`` so far (0 once forgotten)."""
        refused = self._refused.get(key)
        return refused.count if refused is not None else 0

    def close(self) -> None:
        for refused in self._refused.values():
            if refused.again is not None:
                refused.again.cancel()
            if refused.publisher is not None:
                refused.publisher.close()
        self._refused.clear()


_NOTICES: weakref.WeakKeyDictionary[Bus, RefusalNotices] = weakref.WeakKeyDictionary()


def notices_of(bus: Bus) -> RefusalNotices:
    """The notices of ``bus`` (made on first use): the robot's aggregator and its remote
    behaviours share one, so the overall bound holds for both."""
    found = _NOTICES.get(bus)
    if found is None:
        found = _NOTICES[bus] = RefusalNotices(bus)
    return found


def _stderr(line: str) -> None:
    print(line, file=sys.stderr, flush=True)


class RefusalWatch:
    """The sender's side: says (``say``, a line to this process's stderr by default) each
    notice the robot publishes about a key ``mine(key)`` accepts — the keys this process
    publishes. ``who`` starts each line (the component's or behaviour's name)."""

    def __init__(self, bus: Bus, *, mine: Callable[[str], bool], who: str,
                 say: Callable[[str], None] = _stderr) -> None:
        self.bus = bus
        self.mine = mine
        self.who = who
        self.say = say
        self.notices: list[tuple[str, RefusalNotice]] = []
        """``(refused key, notice)`` of the last notices about this process's keys (at most
        100)."""
        self.last_notice_s: float | None = None
        """``time.monotonic()`` when the last of them arrived."""
        self.malformed: dict[str, int] = {}
        self._subscription: Subscription | None = None
        self._head = f"{bus.keys.prefix}/refused/"

    def start(self) -> None:
        """Subscribe (before publishing anything, so the first notice is not missed)."""
        if self._subscription is None:
            self._subscription = self.bus.subscribe(f"{self._head}**", self._on_notice,
                                                    latest=False)

    def _on_notice(self, key: str, payload: bytes, received_ns: int) -> None:
        if not key.startswith(self._head):
            return
        refused_key = f"{self.bus.keys.prefix}/{key[len(self._head):]}"
        if not self.mine(refused_key):
            return
        message = decode_or_count(payload, self.malformed, key, topic=REFUSED)
        if message is None:
            return
        notice: RefusalNotice = message.data
        last = next((seen for key, seen in reversed(self.notices) if key == refused_key), None)
        if last is not None and last.count == notice.count:
            return  # a notice sent once more (module docstring): said already
        self.notices = [*self.notices[-99:], (refused_key, notice)]
        self.last_notice_s = time.monotonic()
        what = "votes" if refused_key.split("/")[2] == "vote" else "samples"
        self.say(f"{self.who}: robot {self.bus.robot!r} REFUSES the {what} on {refused_key} "
                 f"({notice.count} so far, {notice.reason}): {notice.detail}")

    def refusing(self, within_s: float = 2 * NOTICE_PERIOD_S + 0.5) -> RefusalNotice | None:
        """The last notice if it arrived within ``within_s`` (the robot sends one a second
        while it keeps refusing): whether the robot is refusing this process's messages now."""
        if self.last_notice_s is None or time.monotonic() - self.last_notice_s > within_s:
            return None
        return self.notices[-1][1]

    def close(self) -> None:
        if self._subscription is not None:
            self._subscription.close()
            self._subscription = None
