"""The state aggregator: the latest sample of every sensor of one robot.

It subscribes to ``ubf/<robot>/sensor/*/*`` (so sources that start later are picked up
without a restart), keeps the newest valid sample per source, and builds a
:class:`~ubf_async.state.State` snapshot on demand with each source's age and staleness.

A source is **stale** when it has gone quiet: no sample has arrived for longer than its
limit (robot clock) — the configured ``stale_after_s[source]`` if given, else twice the
nominal period the sample itself declares (``period_s`` in the envelope), else
``default_stale_after_s`` — ``None`` by default: a source without a nominal period publishes
events (a radio message), and its last event stays valid until the next. Staleness counts
from arrival, not from the sample's stamp, because some sources are old by design when they
arrive (a camera frame is 0.11 s old when published) and that is not silence; each reading
still reports its age from its stamp.

Malformed samples are rejected, counted per key and logged (the first and every 100th);
they never replace a good sample and never stop the aggregator.
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from ubf_async.action import Action
from ubf_async.bus import Bus, decode_or_count
from ubf_async.component import Component
from ubf_async.protocol import Message, ProtocolError
from ubf_async.state import Reading, State

log = logging.getLogger(__name__)

MAX_SOURCES = 1024
Listener = Callable[[str, "SourceEntry"], None]


@dataclass
class SourceEntry:
    """What the aggregator knows about one source."""

    source: str
    message: Message
    received_ns: int
    """Host monotonic time the bridge received it (for latency measurements)."""
    arrived_ns: int = 0
    """Robot-clock time it was stored (for staleness)."""
    version: int = 1
    """Accepted samples so far (unlike ``seq`` it never restarts)."""
    interval_s: float | None = None
    """Smoothed interval between samples (stamp to stamp)."""
    waiters: list[asyncio.Future[SourceEntry]] = field(default_factory=list)


@dataclass(frozen=True, slots=True)
class SourceInfo:
    source: str
    age_s: float
    stale: bool
    samples: int
    rate_hz: float | None
    schema: str


class StateAggregator(Component):
    def __init__(
        self,
        *,
        bus: Bus,
        name: str = "aggregator",
        stale_after_s: Mapping[str, float] | None = None,
        default_stale_after_s: float | None = None,
        **component_options: float,
    ) -> None:
        super().__init__(bus=bus, name=name, **component_options)
        self.stale_after_s = dict(stale_after_s or {})
        self.default_stale_after_s = default_stale_after_s
        self.entries: dict[str, SourceEntry] = {}
        self.malformed: dict[str, int] = {}
        """Rejected samples per key."""
        self.refused_sources = 0
        self._pending_waiters: dict[str, list[asyncio.Future[SourceEntry]]] = {}
        self._listeners: list[Listener] = []

    def add_listener(self, listener: Listener) -> Callable[[], None]:
        """Call ``listener(source, entry)`` right after each accepted sample is stored, on the
        event loop, before anything else runs (the controller's reflexes use this). A listener
        that raises is logged and removed; the aggregator goes on. Returns a remover."""
        self._listeners.append(listener)

        def remove() -> None:
            if listener in self._listeners:
                self._listeners.remove(listener)

        return remove

    async def run(self) -> None:
        self.subscribe(self.bus.keys.all_sensors, self._on_sample)
        await asyncio.Event().wait()  # samples arrive through the subscription

    # -- ingest (event loop) -----------------------------------------------------------------
    def _on_sample(self, key: str, payload: bytes, received_ns: int) -> None:
        message = decode_or_count(payload, self.malformed, key)
        if message is None:
            return
        try:
            source = self.bus.keys.source_of(key)
        except ProtocolError as exc:  # cannot happen with our key expression; be safe
            self.malformed[key] = self.malformed.get(key, 0) + 1
            log.warning("ignored sample on %s: %s", key, exc)
            return
        self.ingest(source, message, received_ns)

    def ingest(self, source: str, message: Message, received_ns: int) -> None:
        """Store a validated sample (also usable in-process, without the bus)."""
        entry = self.entries.get(source)
        if entry is None:
            if len(self.entries) >= MAX_SOURCES:
                self.refused_sources += 1
                return
            entry = SourceEntry(source, message, received_ns, self.bus.clock.now_ns())
            entry.waiters = self._pending_waiters.pop(source, [])
            self.entries[source] = entry
            log.info("new source %s (%s)", source, message.schema)
        else:
            if message.stamp_ns < entry.message.stamp_ns:
                return  # out of order: keep the newer sample
            dt = (message.stamp_ns - entry.message.stamp_ns) / 1e9
            if dt > 0:
                entry.interval_s = dt if entry.interval_s is None else (
                    0.8 * entry.interval_s + 0.2 * dt
                )
            entry.message = message
            entry.received_ns = received_ns
            entry.arrived_ns = self.bus.clock.now_ns()
            entry.version += 1
        waiters, entry.waiters = entry.waiters, []
        for future in waiters:
            if not future.done():
                future.set_result(entry)
        for listener in tuple(self._listeners):
            try:
                listener(source, entry)
            except Exception:
                log.exception("state listener %r failed: removed", listener)
                self._listeners.remove(listener)

    # -- queries -----------------------------------------------------------------------------
    @staticmethod
    def quiet_s(entry: SourceEntry, now_ns: int) -> float:
        """How long since the newest sample of ``entry`` arrived (robot clock)."""
        return max(0.0, (now_ns - entry.arrived_ns) / 1e9)

    def limit_s(self, entry: SourceEntry) -> float:
        configured = self.stale_after_s.get(entry.source)
        if configured is not None:
            return configured
        if entry.message.period_s is not None:
            return 2.0 * entry.message.period_s
        if self.default_stale_after_s is not None:
            return self.default_stale_after_s
        return math.inf

    def snapshot(
        self, *, previous_action: Action | None = None, now_ns: int | None = None
    ) -> State:
        now = self.bus.clock.now_ns() if now_ns is None else now_ns
        readings = {}
        for source, entry in self.entries.items():
            message = entry.message
            age = max(0.0, (now - message.stamp_ns) / 1e9)
            readings[source] = Reading(
                value=message.data, stamp_ns=message.stamp_ns, seq=message.seq, age_s=age,
                stale=self.quiet_s(entry, now) > self.limit_s(entry),
            )
        return State(readings, now_ns=now, previous_action=previous_action)

    def sources(self) -> list[SourceInfo]:
        now = self.bus.clock.now_ns()
        out = []
        for source, entry in sorted(self.entries.items()):
            age = max(0.0, (now - entry.message.stamp_ns) / 1e9)
            out.append(SourceInfo(
                source=source, age_s=age, stale=self.quiet_s(entry, now) > self.limit_s(entry),
                samples=entry.version,
                rate_hz=1.0 / entry.interval_s if entry.interval_s else None,
                schema=entry.message.schema,
            ))
        return out

    def newest(self) -> SourceEntry | None:
        """The entry holding the most recently stamped sample."""
        return max(self.entries.values(), key=lambda e: e.message.stamp_ns, default=None)

    async def wait_for_update(self, source: str, *, after_version: int = 0) -> SourceEntry:
        """Return the entry of ``source`` once its version exceeds ``after_version``."""
        entry = self.entries.get(source)
        if entry is not None and entry.version > after_version:
            return entry
        future: asyncio.Future[SourceEntry] = asyncio.get_running_loop().create_future()
        if entry is None:
            self._pending_waiters.setdefault(source, []).append(future)
        else:
            entry.waiters.append(future)
        return await future
