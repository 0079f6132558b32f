"""Samples stamped on another clock than the robot's: recognised, counted and reported.

Every ``stamp_ns`` is meant to be on the robot clock (``docs/protocol.md``, *The robot
clock*): simulated time when a simulator publishes ``ubf/<robot>/clock``, else the robot
host's ``CLOCK_MONOTONIC``. A sender that stamps with another clock — the usual case: a
plain script stamping ``time.monotonic_ns()`` or ``time.time_ns()`` while the robot runs on
simulated time — produces ages that mean nothing: a stamp far ahead is refused as from the
future, one far behind is taken with an age of minutes or decades. This module tells such
samples apart so the robot can say so, once per source, with how to fix it.

**The rule** (:func:`foreign_clock`, pure): a stamp ``offset = stamp − now`` away from the
robot clock is from another clock domain when

* ``|offset|`` exceeds :data:`CLOSE_S` (1 s: nearer than that the clocks cannot be told
  apart, and the age is nearly right anyway), and
* it is plausibly **wall-clock time** (``CLOCK_REALTIME``, ``time.time_ns()``): at least
  :data:`REALTIME_FLOOR_NS` (2001-09-09), which neither simulated time nor a host's uptime
  reaches; or
* the robot runs on simulated time and it is within :data:`HOST_MATCH_S` of **this host's
  CLOCK_MONOTONIC** (a sender on the robot's host stamping ``time.monotonic_ns()``); or
* ``|offset|`` exceeds :data:`FAR_S` (10 s): no sample of a running robot's own clock
  arrives ten seconds early (those beyond 0.5 s are refused as from the future anyway) or
  ten seconds late — e.g. simulated-time stamps sent to a robot on wall time.

What it does **not** change: how the sample is judged. A sample stamped ahead is still
refused (``future``), so a foreign stamp never pins a source; one stamped behind is still
taken with its true, large age. Detection only adds the report: :class:`ClockDomainWatch`
counts such samples per source (sensor sources ``"<kind>/<name>"``, remote votes
``"vote/<composite>/<behaviour>"``), logs a warning with the fix — and the process that sent
the sample: the component, pid and host of the heartbeat announcing its publisher ``pub``
(:class:`SenderNames`) — the first time per source
(and every 100th sample after; past :data:`MAX_WARNED_SOURCES` sources one summary per 100
samples, so a flood of names cannot flood the log), and its
:meth:`~ClockDomainWatch.status` goes into the controller's status, which
``python -m ubf_async.inspector state`` shows.

One watch serves a bus (:func:`watch`): the robot's aggregator and its remote behaviours
report into the same table.

The other half — a process learning which clock the robot is on, however long the robot takes
to start — is :mod:`ubf_async.clocks.follow`. This module follows no clock: the state
aggregator, which ingests every sample, stands on the rule, not on the followers.
"""

from __future__ import annotations

import asyncio
import functools
import logging
import time
import weakref
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

from ubf_async.clocks.port import ClockBus, Closing
from ubf_async.errors import ProtocolError
from ubf_async.wire.protocol import clip, decode
from ubf_async.wire.topics import HEARTBEAT, Heartbeat

__all__ = ["CLOSE_NS", "CLOSE_S", "FAR_S", "HOST_MATCH_S", "MAX_REPORTED", "MAX_SOURCES",
           "MAX_WARNED_SOURCES", "NAME_WAIT_S", "REALTIME_FLOOR_NS", "ClockDomainWatch",
           "ClockName", "ForeignSource", "SenderNames", "foreign_clock", "how_to_stamp",
           "sender_name", "the", "watch"]

log = logging.getLogger(__name__)

CLOSE_S = 1.0
"""Stamps nearer than this to the robot clock are never called foreign."""
CLOSE_NS = round(CLOSE_S * 1e9)
FAR_S = 10.0
"""Stamps further than this from the robot clock are foreign whatever they look like."""
HOST_MATCH_S = 5.0
"""How near this host's ``CLOCK_MONOTONIC`` a stamp must be to be called that clock."""
REALTIME_FLOOR_NS = 10**18
"""Stamps from here on (2001-09-09 as Unix time, 31.7 years as uptime or simulated time)
are taken for wall-clock time."""
MAX_SOURCES = 256
"""Sources remembered (the least recently seen forgotten first)."""
MAX_WARNED_SOURCES = 32
"""Sources warned about one by one; beyond them (a flood of names) one summary warning per
100 foreign samples."""
MAX_REPORTED = 32
"""Sources listed in :meth:`ClockDomainWatch.status`."""
NAME_WAIT_S = 3.0
"""How long the first warning about a source waits for the heartbeat naming the process that
sent the sample (a ubf_async component sends one every 0.5 s; a busy one may be late)."""

ClockName = Literal["wall clock", "host monotonic clock", "another clock"]


def foreign_clock(stamp_ns: int, *, now_ns: int, simulated: bool,
                  host_monotonic_ns: int) -> ClockName | None:
    """Which other clock ``stamp_ns`` looks like, or ``None`` if it may be the robot clock
    (now ``now_ns``; ``simulated``: the robot runs on simulated time). The module docstring
    states the rule."""
    offset = stamp_ns - now_ns
    if -CLOSE_NS <= offset <= CLOSE_NS:
        return None
    if stamp_ns >= REALTIME_FLOOR_NS > now_ns:
        return "wall clock"
    if simulated and abs(stamp_ns - host_monotonic_ns) <= HOST_MATCH_S * 1e9:
        return "host monotonic clock"
    if abs(offset) > FAR_S * 1e9:
        return "another clock"
    return None


def the(clock: str) -> str:
    """A :data:`ClockName` in a sentence: "the wall clock", but "another clock"."""
    return clock if clock == "another clock" else f"the {clock}"


def how_to_stamp(robot: str, simulated: bool) -> str:
    """The fix, in one sentence, for a sender stamping on the wrong clock."""
    if simulated:
        return (f"this robot runs on simulated time: stamp with the stamp_ns of the newest "
                f"sample on ubf/{robot}/clock, not the host's clock (docs/protocol.md, "
                f"'The robot clock')")
    return ("this robot runs on its host's CLOCK_MONOTONIC: stamp with time.monotonic_ns() "
            "on that host (a simulated-time stamp means the sender follows a simulator this "
            "robot does not; docs/protocol.md, 'The robot clock')")


@dataclass(slots=True)
class ForeignSource:
    """What the watch knows about one source stamping on another clock."""

    samples: int
    clock: ClockName
    offset_s: float
    """The last such sample's ``stamp − now`` in seconds."""
    sender: str | None = None
    """The process that sent its first such sample, once a heartbeat has named it."""


def sender_name(heartbeat: Heartbeat) -> str:
    """The process a heartbeat describes, for a warning: ``range-left (pid 4242 on box)``."""
    where = " ".join(part for part in (f"pid {heartbeat.pid}" if heartbeat.pid else "",
                                       f"on {heartbeat.host}" if heartbeat.host else "") if part)
    return f"{heartbeat.component} ({where})" if where else heartbeat.component


class SenderNames:
    """Names the process behind a publisher identity (an envelope's ``pub``) from the
    heartbeat that announces it (``publishes``, with the component's ``pid`` and ``host``).

    It listens to the robot's heartbeats only while a name is asked for: :meth:`ask` answers
    each question once — with the name when a heartbeat announcing ``pub`` arrives (a ubf_async
    component sends one every 0.5 s), with ``None`` after ``wait_s``."""

    def __init__(self, bus: ClockBus, *, wait_s: float = NAME_WAIT_S) -> None:
        self.bus = bus
        self.wait_s = wait_s
        self._asked: dict[int, list[Callable[[str | None], None]]] = {}
        self._timers: dict[int, asyncio.TimerHandle] = {}
        self._subscription: Closing | None = None

    def ask(self, pub: int, then: Callable[[str | None], None]) -> None:
        """Call ``then(name)`` once the process publishing as ``pub`` is named, or
        ``then(None)`` after ``wait_s``. On the event loop (called outside one — a unit test
        ingesting by hand — no heartbeat can arrive: ``then(None)`` at once)."""
        try:
            loop = asyncio.get_running_loop()
        except RuntimeError:
            then(None)
            return
        if pub not in self._asked:
            self._asked[pub] = []
            self._timers[pub] = loop.call_later(self.wait_s, self._answer, pub, None)
        self._asked[pub].append(then)
        if self._subscription is None and len(self._asked) == 1:
            # Declared from the loop's own turn: this may run on a transport thread the loop
            # is lent to (a direct subscription's handler), which must not declare.
            loop.call_soon(self._listen)

    def _listen(self) -> None:
        if self._asked and self._subscription is None and not self.bus.closed:
            self._subscription = self.bus.subscribe(self.bus.keys.all_heartbeats,
                                                    self._on_heartbeat)

    def _on_heartbeat(self, key: str, payload: bytes, received_ns: int) -> None:
        try:
            heartbeat = decode(payload, topic=HEARTBEAT).data
        except ProtocolError:
            return  # the robot's health monitor counts it
        for published in heartbeat.publishes:
            if published.pub in self._asked:
                self._answer(published.pub, sender_name(heartbeat))

    def _answer(self, pub: int, name: str | None) -> None:
        timer = self._timers.pop(pub, None)
        if timer is not None:
            timer.cancel()
        for then in self._asked.pop(pub, []):
            then(name)
        if not self._asked and self._subscription is not None:
            self._subscription.close()
            self._subscription = None


class ClockDomainWatch:
    """Counts and reports samples stamped on another clock (module docstring).

    :meth:`check` runs on the event loop for every sample the robot ingests (its common case
    is one subtraction); the rest is bookkeeping for the few that are foreign.
    """

    def __init__(self, *, robot: str, max_sources: int = MAX_SOURCES,
                 senders: SenderNames | None = None) -> None:
        if max_sources < 1:
            raise ValueError(f"max_sources must be ≥ 1, got {max_sources}")
        self.robot = robot
        self.max_sources = max_sources
        self.senders = senders
        """Who names the process behind a sample's ``pub`` (none: warnings name no one)."""
        self.sources: OrderedDict[str, ForeignSource] = OrderedDict()
        """Per source, least recently seen first (bounded by ``max_sources``)."""
        self.total = 0
        """Foreign samples so far, all sources."""
        self.warned_sources = 0
        """Sources warned about one by one (at most :data:`MAX_WARNED_SOURCES`)."""

    def check(self, source: str, stamp_ns: int, *, now_ns: int, simulated: bool,
              pub: int | None = None) -> bool:
        """Whether the sample of ``source`` stamped ``stamp_ns`` is from another clock
        domain (robot clock ``now_ns``); if so count it, and warn the first time per source
        and every 100th sample after. The first warning names the process that sent it, by
        the heartbeat announcing the sample's publisher ``pub`` (:class:`SenderNames`: it
        then comes once that heartbeat has arrived, at most :data:`NAME_WAIT_S` later)."""
        offset = stamp_ns - now_ns
        if -CLOSE_NS <= offset <= CLOSE_NS:
            return False
        clock = foreign_clock(stamp_ns, now_ns=now_ns, simulated=simulated,
                              host_monotonic_ns=time.monotonic_ns())
        if clock is None:
            return False
        self.total += 1
        entry = self.sources.get(source)
        if entry is None:
            entry = self.sources[source] = ForeignSource(0, clock, 0.0)
            if len(self.sources) > self.max_sources:
                self.sources.popitem(last=False)
        else:
            self.sources.move_to_end(source)
        entry.samples += 1
        entry.clock = clock
        entry.offset_s = offset / 1e9
        if entry.samples == 1 and self.warned_sources < MAX_WARNED_SOURCES:
            self.warned_sources += 1
            warn = functools.partial(self._warn_first, clip(source), entry, clock, offset,
                                     simulated, pub)
            if pub is None or self.senders is None:
                warn(None)
            else:
                self.senders.ask(pub, warn)
        elif entry.samples % 100 == 0:
            log.warning("%s: %d samples stamped on %s so far", clip(source),
                        entry.samples, the(clock))
        elif self.warned_sources >= MAX_WARNED_SOURCES and self.total % 100 == 1:
            log.warning("%d samples stamped on another clock so far, from more sources than "
                        "warned about one by one (%d; a flood of names?): see the "
                        "controller's status", self.total, MAX_WARNED_SOURCES)
        return True

    def _warn_first(self, source: str, entry: ForeignSource, clock: ClockName, offset: int,
                    simulated: bool, pub: int | None, sender: str | None) -> None:
        entry.sender = sender
        if pub is None or self.senders is None:
            by = ""  # a plain client without ``pub``: nothing names it
        elif sender is None:
            by = (f", sent by publisher {pub} (which no heartbeat named within "
                  f"{self.senders.wait_s:g} s: not a ubf_async component?),")
        else:
            by = f", sent by {sender},"
        log.warning("%s: sample stamped %+.6g s from the robot clock%s looks like %s, not the "
                    "robot's: its age means nothing (%s); %s", source, offset / 1e9, by,
                    the(clock), "refused as from the future" if offset > 0
                    else "taken with that age", how_to_stamp(self.robot, simulated))

    def check_on(self, bus: ClockBus, source: str, stamp_ns: int, now_ns: int, *,
                 pub: int | None = None) -> bool:
        """:meth:`check` with ``bus.clock``'s kind (simulated or not)."""
        return self.check(source, stamp_ns, now_ns=now_ns,
                          simulated=bus.clock.is_simulated, pub=pub)

    def count(self, source: str) -> int:
        entry = self.sources.get(source)
        return entry.samples if entry is not None else 0

    def status(self) -> list[dict[str, Any]]:
        """The sources seen stamping on another clock, most recently seen first (at most
        :data:`MAX_REPORTED`): ``{"source", "samples", "clock", "offset_s"}`` each, and
        ``"sender"`` once the process that sent them is named."""
        out: list[dict[str, Any]] = []
        for source, entry in reversed(self.sources.items()):
            if len(out) >= MAX_REPORTED:
                break
            out.append({"source": clip(source), "samples": entry.samples,
                        "clock": entry.clock, "offset_s": entry.offset_s}
                       | ({"sender": entry.sender} if entry.sender else {}))
        return out


_WATCHES: weakref.WeakKeyDictionary[ClockBus, ClockDomainWatch] = weakref.WeakKeyDictionary()


def watch(bus: ClockBus) -> ClockDomainWatch:
    """The watch of ``bus`` (made on first use): everything ingesting samples on the bus
    reports into one table. A bus-like stand-in that cannot be weakly referenced (a test
    double) gets a watch of its own at each call: keep the one returned."""
    robot = bus.keys.robot
    try:
        found = _WATCHES.get(bus)
        if found is None:
            found = _WATCHES[bus] = ClockDomainWatch(robot=robot, senders=SenderNames(bus))
    except TypeError:  # not hashable or not weakly referenceable
        return ClockDomainWatch(robot=robot)
    return found
