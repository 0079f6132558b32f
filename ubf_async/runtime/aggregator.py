"""The state aggregator: the latest sample of every sensor of one robot.

It subscribes to ``ubf/<robot>/sensor/*/*`` (so sources that start later are picked up
without a restart), keeps the newest valid sample per source, and builds a
:class:`~ubf_async.core.state.State` snapshot on demand with each source's age and staleness.

A source is **stale** when it has gone quiet: no sample has arrived for longer than its
limit (robot clock) — the configured ``stale_after_s[source]`` if given, else
:data:`STALE_PERIODS` (1.5) times the nominal period the sample itself declares
(``period_s`` in the envelope), else ``default_stale_after_s`` — ``None`` by default: a
source without a nominal period publishes events (a radio message), and its last event stays
valid until the next. Staleness counts from arrival, not from the sample's stamp, because
some sources are old by design when they arrive (a camera frame is 0.11 s old when
published) and that is not silence; each reading still reports its age from its stamp.
1.5 periods, not 2, so that a source is reported stale within 2 of its periods *end to end*
(its last sample's transit and the next tick come on top of the limit).

What is refused — each counted and logged (the first and every 100th per reason):

* malformed samples (per key, :attr:`StateAggregator.malformed`);
* a source name longer than :data:`~ubf_async.wire.topics.MAX_NAME_CHARS` (the controller
  copies source names into its commands);
* a sample stamped more than ``future_tolerance_s`` ahead of the robot clock, and one not
  newer from its publisher than what is held (:mod:`ubf_async.runtime.ordering`): a future stamp
  cannot pin a source, a replay cannot roll it back;
* a new source when the table is full and every source in it is protected.

None of them replaces a good sample or stops the aggregator. The table is bounded: a source
silent for ``forget_after_s`` is forgotten, and when :data:`MAX_SOURCES` sources are held
a new one evicts the one silent longest — except the ``protected_sources`` (the devices the
robot declares), which are never forgotten nor evicted. Forgetting and evicting are the
table's housekeeping, not refusals: they are counted apart (:meth:`StateAggregator.dropped`).

A source whose publisher has **left** (its component said goodbye) or is **gone** (its token
vanished without one) is reported so — by whoever knows the components, ``departures``
(launch gives its :class:`~ubf_async.runtime.component.HealthMonitor`) — instead of as a
source growing stale for no reason given. For the behaviours nothing changes: staleness is the
robot clock's rule above, whatever the wall time at which a departure was heard.

**Threads.** Samples are stored on the event loop, except on the **reflex lane**
(:meth:`StateAggregator.open_lane`, opened by a controller on a wall-clock robot): a valid
sample of a source that triggers a tick is ingested — and its tick run, by the sample hook —
on the transport's thread that brought it, without waking the loop. Everything that reads or
changes the aggregator's state therefore holds :attr:`StateAggregator.lock` (its methods do;
the controller holds it for its ticks, and the robot's tree changers for theirs): one thread
at a time, samples of one key in the order they came (:class:`~ubf_async.runtime.bus.Lane`).
What belongs to the loop — a :meth:`~StateAggregator.wait_for_update` future, a refusal
notice — is handed to it (:meth:`~ubf_async.runtime.bus.Bus.call_on_loop`). The lane does
not take a sample stamped far from the robot clock (its clock-domain check belongs to the
loop) nor any sample on simulated time (the lockstep orders by simulated time, on the loop).
"""

from __future__ import annotations

import asyncio
import logging
import math
import threading
import time
from array import array
from collections import Counter, OrderedDict
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

from ubf_async import throttle
from ubf_async.clocks import clockdomain
from ubf_async.clocks.clock import SilenceLimit
from ubf_async.core.action import Action
from ubf_async.core.fusion import CameraFusion
from ubf_async.core.state import Reading, State
from ubf_async.errors import ProtocolError
from ubf_async.net.transport import Declaration
from ubf_async.runtime import refusals
from ubf_async.runtime.bus import Bus, Lane, Subscription
from ubf_async.runtime.component import Component, Departure
from ubf_async.runtime.hooks import add_hook, run_hooks
from ubf_async.runtime.ordering import Refusal, SampleOrder, ahead_of_clock
from ubf_async.wire.protocol import Message, clip, count_malformed, decode
from ubf_async.wire.topics import MAX_NAME_CHARS, Topic, sensor_topic

__all__ = ["DEFAULT_FORGET_AFTER_S", "DEFAULT_FUTURE_TOLERANCE_S", "MAX_SOURCES", "STALE_PERIODS",
           "Departures", "IngestHook", "ReceiveHook", "RecentCounts", "SampleHook", "SourceEntry",
           "SourceInfo", "StateAggregator"]

log = logging.getLogger(__name__)

MAX_SOURCES = 128
"""Sources held at once. A robot has a few dozen; every held source costs each tick a
reading (≈ 2.3 µs each: 1024 sources made a tick ≈ 5 ms over zenoh), so a flood of junk
keys is capped well below that (bench/flood.py measures it)."""
STALE_PERIODS = 1.5
"""A source declaring ``period_s`` is stale after this many periods without a sample."""
DEFAULT_FUTURE_TOLERANCE_S = 0.5
"""How far ahead of the robot clock a stamp may be. On one host with the wall clock stamps
are never ahead; with simulated time a device in another process may have seen a clock
sample before the robot did, by a few ms of wall time — multiplied by the simulation speed
(20 ms at 20× is 0.4 s). A sample stamped further ahead is refused."""
DEFAULT_FORGET_AFTER_S = 60.0
"""An unprotected source silent this long (robot clock) is dropped from the state."""

SampleHook = Callable[[str, "SourceEntry"], None]
"""``callback(source, entry)``: an accepted sample was stored
(:meth:`StateAggregator.on_sample`)."""
ReceiveHook = Callable[[str, bytes, int], None]
"""``callback(key, payload, received_ns)``: a raw sample reached the aggregator."""
IngestHook = Callable[[str, Message, int], None]
"""``callback(source, message, received_ns)``: a decoded sample is offered to ingest."""


class RecentCounts:
    """Roughly how many samples each source name sent in the last one to two windows.

    A count-min sketch (fixed memory, whatever the number of names): ``rows`` arrays of
    ``width`` counters, two windows (this one and the last) rolled every ``window_ns`` of
    the robot clock. A flood of distinct junk names adds about ``flood / width`` to every
    estimate per window, far below a real sensor's own rate; the aggregator uses it so that
    a name seen once does not push out a source that keeps publishing.
    """

    __slots__ = ("_current", "_previous", "_seeds", "_width", "_window_ns", "_window_start")

    def __init__(self, *, width: int = 16384, rows: int = 2, window_ns: int = 10**9) -> None:
        self._width = width
        self._window_ns = window_ns
        self._seeds = tuple(range(rows))
        self._current = [array("I", bytes(4 * width)) for _ in self._seeds]
        self._previous = [array("I", bytes(4 * width)) for _ in self._seeds]
        self._window_start = 0

    def _roll(self, now_ns: int) -> None:
        elapsed = now_ns - self._window_start
        if 0 <= elapsed < self._window_ns:
            return
        if 0 <= elapsed < 2 * self._window_ns:
            self._previous, self._current = self._current, self._previous
        else:  # two windows or more (or a clock that went back): forget everything
            for counters in self._previous:
                counters[:] = array("I", bytes(4 * self._width))
        for counters in self._current:
            counters[:] = array("I", bytes(4 * self._width))
        self._window_start = now_ns

    def add(self, name: str, now_ns: int) -> int:
        """Count one sample of ``name``; returns its estimate including this one."""
        return self._count(name, now_ns, 1)

    def estimate(self, name: str, now_ns: int) -> int:
        """Samples of ``name`` in this window and the last (never less than the truth)."""
        return self._count(name, now_ns, 0)

    def _count(self, name: str, now_ns: int, add: int) -> int:
        self._roll(now_ns)
        estimate = 1 << 33
        for seed, current, previous in zip(self._seeds, self._current, self._previous,
                                           strict=True):
            i = hash((seed, name)) % self._width
            if add and current[i] < 0xFFFFFFFF:
                current[i] += add
            estimate = min(estimate, current[i] + previous[i])
        return estimate


@dataclass
class SourceEntry:
    """What the aggregator knows about one source."""

    source: str
    message: Message
    received_ns: int
    """Host monotonic time the bridge received it (for latency measurements)."""
    arrived_ns: int = 0
    """Robot-clock time it was stored (for staleness)."""
    arrived_wall_ns: int = field(default_factory=time.monotonic_ns)
    """Host monotonic time it was stored (staleness while simulated time stalls)."""
    version: int = 1
    """Accepted samples so far (unlike ``seq`` it never restarts)."""
    interval_s: float | None = None
    """Smoothed interval between samples (stamp to stamp)."""
    waiters: list[asyncio.Future[SourceEntry]] = field(default_factory=list)
    order: SampleOrder = field(default_factory=SampleOrder)
    """Which samples of this source are newer (:mod:`ubf_async.runtime.ordering`)."""
    refused: Counter[str] = field(default_factory=Counter)
    """Valid samples of this source refused, per :class:`~ubf_async.runtime.ordering.Refusal`."""


@dataclass(frozen=True, slots=True)
class SourceInfo:
    source: str
    age_s: float
    stale: bool
    samples: int
    rate_hz: float | None
    schema: str
    refused: Mapping[str, int] = field(default_factory=dict)
    """Valid samples of this source refused, per reason (``future``, ``out_of_order``)."""
    stale_why: str | None = None
    """For a stale source: how long it has been quiet, in the clock that made it stale."""
    departed: Departure | None = None
    """Its publisher left or is gone (module docstring)."""


class Departures(Protocol):
    """Who knows which components have left
    (:class:`~ubf_async.runtime.component.HealthMonitor`)."""

    def departure(self, key: str, pub: int | None) -> Departure | None:
        """How the component publishing ``key`` (as ``pub``) went, if it has."""


class StateAggregator(Component):
    """Keeps the newest sample of every source (module docstring for the rules).

    ``future_tolerance_s``: how far ahead of the robot clock a stamp may be
    (:data:`DEFAULT_FUTURE_TOLERANCE_S`). ``forget_after_s``: silence after which an
    unprotected source is dropped (``None``: never). ``protected_sources``: sources never
    forgotten nor evicted (launch passes the devices of the robot file).
    ``notify_refusals``: also tell each refused or malformed sample's sender, on
    ``ubf/<robot>/refused/...`` (:mod:`ubf_async.runtime.refusals`) — the robot's aggregator does;
    a remote behaviour's own copy of the state does not speak for the robot.
    ``departures``: who says which sources' publishers have left (module docstring).
    ``fused``: sources each snapshot derives from others (a robot file's ``controller: fuse``,
    :mod:`ubf_async.core.fusion`): in the state, never in the table of what arrived.
    """

    def __init__(
        self,
        *,
        bus: Bus,
        name: str = "aggregator",
        stale_after_s: Mapping[str, float] | None = None,
        default_stale_after_s: float | None = None,
        future_tolerance_s: float = DEFAULT_FUTURE_TOLERANCE_S,
        forget_after_s: float | None = DEFAULT_FORGET_AFTER_S,
        protected_sources: Iterable[str] = (),
        max_sources: int = MAX_SOURCES,
        notify_refusals: bool = False,
        departures: Departures | None = None,
        fused: Iterable[CameraFusion] = (),
        **component_options: float,
    ) -> None:
        super().__init__(bus=bus, name=name, **component_options)
        self.departures = departures
        self.fused = tuple(fused)
        if not (math.isfinite(future_tolerance_s) and future_tolerance_s >= 0):
            raise ValueError(f"future_tolerance_s must be finite and ≥ 0, got "
                             f"{future_tolerance_s}")
        if forget_after_s is not None and not forget_after_s > 0:
            raise ValueError(f"forget_after_s must be > 0 or None, got {forget_after_s}")
        if max_sources < 1:
            raise ValueError(f"max_sources must be ≥ 1, got {max_sources}")
        self.stale_after_s = dict(stale_after_s or {})
        self.default_stale_after_s = default_stale_after_s
        self.future_tolerance_s = future_tolerance_s
        self._future_tolerance_ns = round(future_tolerance_s * 1e9)
        self.forget_after_s = forget_after_s
        self.protected_sources = frozenset(protected_sources)
        self.max_sources = max_sources
        self.entries: dict[str, SourceEntry] = {}
        self._recent = RecentCounts()
        self._silence: OrderedDict[str, None] = OrderedDict()
        """Unprotected sources, the one silent longest first (eviction order)."""
        self.malformed: dict[str, int] = {}
        """Rejected samples per key (at most :data:`~ubf_async.wire.protocol.MAX_COUNTED_KEYS`
        keys)."""
        self.refused: Counter[str] = Counter()
        """Valid samples refused, per :class:`~ubf_async.runtime.ordering.Refusal` (all sources)."""
        self.evicted = 0
        """Sources dropped to make room for a new one."""
        self.forgotten = 0
        """Sources dropped after ``forget_after_s`` of silence."""
        self._pending_waiters: dict[str, list[asyncio.Future[SourceEntry]]] = {}
        self._sample_hooks: list[SampleHook] = []
        self._receive_hooks: list[ReceiveHook] = []
        self._ingest_hooks: list[IngestHook] = []
        self.subscription: Subscription | None = None
        """This run's subscription to the sensors (its ``stats``: the bridge's counts)."""
        self.clock_domain = clockdomain.watch(bus)
        """Samples stamped on another clock than the robot's, per source
        (:mod:`ubf_async.clocks.clockdomain`; shared with everything else on this bus)."""
        self.notices = refusals.notices_of(bus) if notify_refusals else None
        """Where refusals are told to their senders (``notify_refusals``)."""
        self.lock = threading.RLock()
        """Held by whatever reads or changes this aggregator's state — and by the ticks of
        its controller, whose reflex lane stores samples on the transport's thread (module
        docstring). Re-entrant: a triggered tick runs inside :meth:`ingest`."""
        self._lane_trigger: Callable[[str], bool] | None = None
        self._declared_keys: dict[str, Declaration] = {}
        """The lane's sources whose keys are declared to the network (:meth:`open_lane`)."""
        self.close_on_exit(self._undeclare_keys)  # (after the subscription has closed)

    @property
    def refused_sources(self) -> int:
        """New sources refused because the table was full of protected ones."""
        return self.refused[Refusal.FULL]

    # -- hooks -------------------------------------------------------------------------------
    # Observers of the ingest path, in the order a sample meets them: on_receive (raw bytes),
    # on_ingest (decoded and valid), on_sample (accepted and stored). Each runs where the
    # sample is stored — on the event loop, or on the reflex lane's thread holding the lock
    # (module docstring) — synchronously, in the order the hooks were added; one that raises
    # is logged and removed, and the aggregator goes on. Each returns a remover. With none
    # added a sample pays one truth test per point.

    def on_sample(self, callback: SampleHook) -> Callable[[], None]:
        """Call ``callback(source, entry)`` right after each accepted sample is stored (entry
        updated, waiters of :meth:`wait_for_update` resolved), before anything else runs.
        Not called for a sample that is malformed or refused. The controller's triggered
        ticks (reflexes, ``sync``, ``event``) run from this hook, so a hook added before the
        controller starts runs before its tick, one added after it runs after the tick."""
        return add_hook(self._sample_hooks, callback)

    def on_receive(self, callback: ReceiveHook) -> Callable[[], None]:
        """Call ``callback(key, payload, received_ns)`` when the bridge hands the aggregator
        a raw sample from the bus (``received_ns``: host monotonic time of its zenoh
        callback), before it is decoded: every sample, malformed ones too. Samples given to
        :meth:`ingest` directly do not pass here."""
        return add_hook(self._receive_hooks, callback)

    def on_ingest(self, callback: IngestHook) -> Callable[[], None]:
        """Call ``callback(source, message, received_ns)`` when a decoded, valid sample is
        offered to :meth:`ingest` (from the bus or in-process), before the aggregator's own
        checks: the sample may still be refused (future stamp, out of order, table full)."""
        return add_hook(self._ingest_hooks, callback)

    def open_lane(self, triggers: Callable[[str], bool]) -> Callable[[], None]:
        """Open the reflex lane (module docstring) for the sources ``triggers(source)``
        names: a controller's that tick it. Returns the closer: it takes :attr:`lock`, so
        once it returns no sample is on the lane and none follows.

        The keys of the robot's own sources among them (:attr:`protected_sources`) are
        declared to the network (:meth:`Bus.declare_key
        <ubf_async.runtime.bus.Bus.declare_key>`), which then delivers their samples faster;
        they stay declared as long as the subscription they serve, until the aggregator
        closes. A source attached later takes the lane all the same."""
        self._lane_trigger = triggers
        for source in sorted(self.protected_sources):
            if source not in self._declared_keys and source.count("/") == 1 and triggers(source):
                self._declared_keys[source] = self.bus.declare_key(
                    self.bus.keys.sensor(*source.split("/")))

        def close() -> None:
            with self.lock:
                if self._lane_trigger is triggers:
                    self._lane_trigger = None

        return close

    async def _undeclare_keys(self) -> None:
        declared, self._declared_keys = self._declared_keys, {}
        for declaration in declared.values():
            declaration.undeclare()

    async def run(self) -> None:
        self.subscription = self.subscribe_screened(
            self.bus.keys.all_sensors, _SensorScreen(self), direct=True, lane=_ReflexLane(self))
        forget_after_s = self.forget_after_s
        if forget_after_s is None:
            await asyncio.Event().wait()  # samples arrive through the subscription
            return
        while True:  # samples arrive through the subscription; this only forgets
            await self.bus.clock.sleep(min(1.0, forget_after_s / 4))
            with self.lock:
                self.forget_silent()

    # -- ingest (event loop) -----------------------------------------------------------------
    def _on_decoded(self, key: str, payload: bytes, received_ns: int,
                    decoded: tuple[str, Message]) -> None:
        if self._receive_hooks:
            run_hooks(self._receive_hooks, "receive", key, payload, received_ns)
        source, message = decoded
        self._ingest(source, message, received_ns)  # (the subscription holds the lock)

    def _on_malformed(self, key: str, payload: bytes, received_ns: int, error: ProtocolError,
                      count: int) -> None:
        if self._receive_hooks:
            run_hooks(self._receive_hooks, "receive", key, payload, received_ns)
        count_malformed(self.malformed, key, error, count)
        if self.notices is not None:
            self.notices.report(key, "malformed", f"malformed sample: {error}")

    def _refuse(self, reason: Refusal, source: str, detail: str,
                entry: SourceEntry | None = None) -> None:
        self.refused[reason] += 1
        if entry is not None:
            entry.refused[reason] += 1
        n = self.refused[reason]
        if throttle.first_and_every(n):
            log.warning("refused sample #%d (%s) of %s: %s", n, reason, clip(source), detail)
        if self.notices is not None:  # (it publishes: on the loop, also for a lane's sample)
            self.bus.call_on_loop(self.notices.report, f"{self.bus.keys.prefix}/sensor/{source}",
                                  reason, detail)

    def ingest(self, source: str, message: Message, received_ns: int) -> bool:
        """Store a validated sample (also usable in-process, without the bus); returns
        whether it was taken (module docstring for what is refused)."""
        with self.lock:
            return self._ingest(source, message, received_ns)

    def _ingest(self, source: str, message: Message, received_ns: int) -> bool:
        if self._ingest_hooks:
            run_hooks(self._ingest_hooks, "ingest", source, message, received_ns)
        if len(source) > MAX_NAME_CHARS:
            self._refuse(Refusal.NAME_TOO_LONG, source,
                         f"{len(source)} characters, at most {MAX_NAME_CHARS}")
            return False
        now = self.bus.clock.now_ns()
        entry = self.entries.get(source)
        # Recent counts decide evictions: needed for newcomers and for the sources that may be
        # evicted, never for the robot's own once held (the reflex path skips the hashing).
        count = (self._recent.add(source, now)
                 if entry is None or source not in self.protected_sources else 0)
        if not -clockdomain.CLOSE_NS <= message.stamp_ns - now <= clockdomain.CLOSE_NS:
            self.clock_domain.check_on(self.bus, source, message.stamp_ns, now,
                                       pub=message.pub)  # then judged
        if ahead_of_clock(message.stamp_ns, now, self._future_tolerance_ns):
            self._refuse(Refusal.FUTURE, source,
                         f"stamped {(message.stamp_ns - now) / 1e9:.3g}s ahead of the robot "
                         f"clock (tolerance {self.future_tolerance_s:g}s){self._clock_hint()}",
                         entry)
            return False
        if entry is None:
            if len(self.entries) >= self.max_sources and not self._make_room(source, count, now):
                self._refuse(Refusal.FULL, source,
                             f"{len(self.entries)} sources held, none of them both unprotected "
                             f"and less busy")
                return False
            entry = SourceEntry(source, message, received_ns, now)
            entry.order.accept(pub=message.pub, seq=message.seq, stamp_ns=message.stamp_ns)
            entry.waiters = self._pending_waiters.pop(source, [])
            self.entries[source] = entry
            log.info("new source %s (%s)", source, message.schema)
        else:
            if not entry.order.accept(pub=message.pub, seq=message.seq,
                                      stamp_ns=message.stamp_ns):
                self._refuse(Refusal.OUT_OF_ORDER, source,
                             f"seq {message.seq} (pub {message.pub}) not newer than held", entry)
                return False
            dt = (message.stamp_ns - entry.message.stamp_ns) / 1e9
            if dt > 0:
                entry.interval_s = dt if entry.interval_s is None else (
                    0.8 * entry.interval_s + 0.2 * dt
                )
            entry.message = message
            entry.received_ns = received_ns
            entry.arrived_ns = now
            entry.arrived_wall_ns = time.monotonic_ns()
            entry.version += 1
        if source not in self.protected_sources:
            self._silence[source] = None
            self._silence.move_to_end(source)
        if entry.waiters:
            waiters, entry.waiters = entry.waiters, []
            self.bus.call_on_loop(_resolve, waiters, entry)
        if self._sample_hooks:
            run_hooks(self._sample_hooks, "sample", source, entry)
        return True

    # -- bounds ------------------------------------------------------------------------------
    def _drop(self, source: str) -> None:
        entry = self.entries.pop(source)
        self._silence.pop(source, None)
        if entry.waiters:  # whoever waits for it still gets its next sample
            self._pending_waiters.setdefault(source, []).extend(entry.waiters)

    def _make_room(self, newcomer: str, newcomer_count: int, now_ns: int) -> bool:
        """Evict the unprotected source silent longest if it has sent fewer samples lately
        than the newcomer (so a flood of names seen once cannot push out a source that keeps
        publishing, while a real new sensor gets in by its second sample at the latest);
        False if nothing may be evicted."""
        self.forget_silent(now_ns)
        if len(self.entries) < self.max_sources:
            return True
        if not self._silence:
            return False
        victim = next(iter(self._silence))
        if self._recent.estimate(victim, now_ns) >= newcomer_count:
            return False
        self._drop(victim)
        self.evicted += 1
        if throttle.first_and_every(self.evicted):
            log.warning("source table full (%d): evicted %s, silent longest, for %s "
                        "(eviction #%d)", self.max_sources, victim, newcomer, self.evicted)
        return True

    def forget_silent(self, now_ns: int | None = None) -> int:
        """Drop unprotected sources silent for ``forget_after_s``; returns how many."""
        if self.forget_after_s is None:
            return 0
        now = self.bus.clock.now_ns() if now_ns is None else now_ns
        limit_ns = round(self.forget_after_s * 1e9)
        dropped = 0
        while self._silence:
            source = next(iter(self._silence))
            if now - self.entries[source].arrived_ns <= limit_ns:
                break
            self._drop(source)
            dropped += 1
            log.info("forgot source %s: silent for more than %gs", source, self.forget_after_s)
        self.forgotten += dropped
        return dropped

    # -- queries -----------------------------------------------------------------------------
    def _clock_hint(self) -> str:
        if not self.bus.clock.is_simulated:
            return ""
        return ("; this robot runs on simulated time: stamp with the newest time seen on "
                "ubf/<robot>/clock, not the host's clock (docs/protocol.md)")

    def is_stale(self, entry: SourceEntry, now_ns: int, wall_now_ns: int) -> bool:
        """Whether ``entry`` has been quiet beyond its limit: in robot time, or — so that a
        dead simulator cannot keep dead data fresh — in wall time while the clock's source is
        silent, as :class:`~ubf_async.clocks.clock.SilenceLimit` rules."""
        return self.stale_why(entry, now_ns, wall_now_ns) is not None

    def stale_why(self, entry: SourceEntry, now_ns: int, wall_now_ns: int) -> str | None:
        """``None`` for a fresh ``entry``; for a stale one, how long it has been quiet, in
        the clock that made it stale (:meth:`~ubf_async.clocks.clock.SilenceLimit.overdue`)."""
        limit = self.limit_s(entry)
        if limit == math.inf:
            return None
        if (now_ns - entry.arrived_ns <= limit * 1e9
                and wall_now_ns - entry.arrived_wall_ns < limit * 1e9):
            return None  # the common case, decided without the clock's stall bookkeeping
        return SilenceLimit(limit_s=limit).overdue(
            self.bus.clock, since_ns=entry.arrived_ns, since_wall_ns=entry.arrived_wall_ns,
            now_ns=now_ns, wall_now_ns=wall_now_ns)

    def fresh(self, source: str, now_ns: int | None = None) -> bool:
        """Whether ``source`` has a sample that is not stale."""
        entry = self.entries.get(source)
        if entry is None:
            return False
        now = self.bus.clock.now_ns() if now_ns is None else now_ns
        return not self.is_stale(entry, now, time.monotonic_ns())

    def limit_s(self, entry: SourceEntry) -> float:
        configured = self.stale_after_s.get(entry.source)
        if configured is not None:
            return configured
        if entry.message.period_s is not None:
            return STALE_PERIODS * entry.message.period_s
        if self.default_stale_after_s is not None:
            return self.default_stale_after_s
        return math.inf

    def snapshot(
        self, *, previous_action: Action | None = None, now_ns: int | None = None
    ) -> State:
        with self.lock:
            now = self.bus.clock.now_ns() if now_ns is None else now_ns
            wall_now = time.monotonic_ns()
            readings = {}
            for source, entry in self.entries.items():
                message = entry.message
                age = max(0.0, (now - message.stamp_ns) / 1e9)
                readings[source] = Reading(
                    value=message.data, stamp_ns=message.stamp_ns, seq=message.seq, age_s=age,
                    stale=self.is_stale(entry, now, wall_now),
                )
        for fusion in self.fused:
            fusion.add_to(readings)
        return State(readings, now_ns=now, previous_action=previous_action)

    def sources(self) -> list[SourceInfo]:
        with self.lock:
            return self._sources()

    def _sources(self) -> list[SourceInfo]:
        now = self.bus.clock.now_ns()
        wall_now = time.monotonic_ns()
        out = []
        for source, entry in sorted(self.entries.items()):
            age = max(0.0, (now - entry.message.stamp_ns) / 1e9)
            why = self.stale_why(entry, now, wall_now)
            departed = None
            if self.departures is not None:
                kind, _, name = source.partition("/")
                departed = self.departures.departure(self.bus.keys.sensor(kind, name),
                                                     entry.message.pub)
            out.append(SourceInfo(
                source=source, age_s=age, stale=why is not None, stale_why=why,
                samples=entry.version,
                rate_hz=1.0 / entry.interval_s if entry.interval_s else None,
                schema=entry.message.schema, refused=dict(entry.refused), departed=departed,
            ))
        return out

    def refusals(self) -> dict[str, int]:
        """Everything refused so far: per reason, plus ``malformed`` (all keys)."""
        with self.lock:
            return {**{str(k): v for k, v in sorted(self.refused.items())},
                    "malformed": sum(self.malformed.values())}

    def dropped(self) -> dict[str, int]:
        """The table's housekeeping so far: sources ``evicted`` to make room for a new one,
        and ``forgotten`` after ``forget_after_s`` of silence — not refusals."""
        with self.lock:
            return {"evicted": self.evicted, "forgotten": self.forgotten}

    def newest(self) -> SourceEntry | None:
        """The entry holding the most recently stamped sample."""
        with self.lock:
            return max(self.entries.values(), key=lambda e: e.message.stamp_ns, default=None)

    async def wait_for_update(self, source: str, *, after_version: int = 0) -> SourceEntry:
        """Return the entry of ``source`` once its version exceeds ``after_version``."""
        future: asyncio.Future[SourceEntry] = asyncio.get_running_loop().create_future()
        with self.lock:  # a lane's sample may be stored meanwhile: checked and added at once
            entry = self.entries.get(source)
            if entry is not None and entry.version > after_version:
                return entry
            if entry is None:
                self._pending_waiters.setdefault(source, []).append(future)
            else:
                entry.waiters.append(future)
        return await future


def _resolve(waiters: list[asyncio.Future[SourceEntry]], entry: SourceEntry) -> None:
    """Resolve :meth:`StateAggregator.wait_for_update`'s waiters (on the loop)."""
    for future in waiters:
        if not future.done():
            future.set_result(entry)


_LANE_CLOSE_NS = clockdomain.CLOSE_NS // 2
"""How near the robot clock a sample's stamp must be to take the lane."""


class _ReflexLane(Lane):
    """The aggregator's :class:`~ubf_async.runtime.bus.Lane`: a valid sample of a source the
    open lane's controller ticks on, on a wall-clock robot, stamped near the robot clock
    (else its clock-domain check, which may ask the loop who sent it, would run on the
    lane)."""

    def __init__(self, aggregator: StateAggregator) -> None:
        self._aggregator = aggregator
        self.lock = aggregator.lock

    def takes(self, key: str, decoded: tuple[str, Message]) -> bool:
        aggregator = self._aggregator
        triggers = aggregator._lane_trigger
        if triggers is None:
            return False
        clock = aggregator.bus.clock  # (read each time: a clock follower may swap it)
        source, message = decoded
        # Half the clock domain's "close": ingest, a moment later, cannot find it far.
        return (not clock.is_simulated and triggers(source)
                and -_LANE_CLOSE_NS <= message.stamp_ns - clock.now_ns() <= _LANE_CLOSE_NS)


class _SensorScreen:
    """The aggregator's :class:`~ubf_async.runtime.bus.Screen`: a sample is decoded and
    validated as its kind's topic on the transport's thread, so garbage on a sensor's key is
    refused before it can replace that sensor's newest valid sample (and counted, on the loop,
    in :attr:`StateAggregator.malformed`)."""

    def __init__(self, aggregator: StateAggregator) -> None:
        self._keys = aggregator.bus.keys
        self.accept = aggregator._on_decoded
        self.refuse = aggregator._on_malformed
        self._parsed: dict[str, tuple[str, Topic[Any] | None]] = {}
        """Each sensor key's source and topic, parsed once (the reflex path's every sample
        would parse it again); bounded like the sources, since keys come from the network."""

    def check(self, key: str, payload: bytes) -> tuple[str, Message]:
        # A declared kind (ubf_async.wire.topics) only takes its own schema: behaviours read its
        # samples as that type. Other kinds take any schema, checked generically.
        parsed = self._parsed.get(key)
        if parsed is None:
            source = self._keys.source_of(key)  # (a key that is no sensor's raises: not kept)
            parsed = (source, sensor_topic(source))
            if len(self._parsed) >= MAX_SOURCES:
                self._parsed.clear()
            self._parsed[key] = parsed
        source, topic = parsed
        return source, decode(payload) if topic is None else decode(payload, topic=topic)
