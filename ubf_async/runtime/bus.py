"""The bus: the bridge from the transport's threads into asyncio.

A :class:`Bus` moves its bytes through a transport, which opens and owns the session: zenoh
(:meth:`Bus.open` → :meth:`ZenohTransport.open <ubf_async.net.transport.ZenohTransport.open>`,
what runs) or the in-process transport (``Bus(transport=InProcessTransport())``,
:mod:`ubf_async.net.inprocess`, for unit tests). Everything below is the same on both; the bus
never imports zenoh. How a session is configured is :mod:`ubf_async.net.options`; the
command-line flags that make them, :mod:`ubf_async.cli.args`; waiting for a robot to attach to,
:mod:`ubf_async.cli.attach`.

zenoh-python is synchronous and runs subscriber callbacks on its own threads. The bridge
here is deliberate about that hand-off:

* the transport's callback does almost nothing: it copies the key and payload bytes, stores
  them and, if no drain is already pending, schedules one with ``loop.call_soon_threadsafe``
  (``loop.call_soon`` for a transport whose callbacks run on the loop) — it never calls the
  transport, never blocks and never runs user code;
* the drain runs on the event loop and calls the handler for each stored sample;
* in **latest** mode a burst on one key coalesces to the newest sample (what a state
  aggregator wants); in **every** mode samples queue up to a bound, and overflow drops the
  oldest and is counted;
* a **screened** subscription (:meth:`Bus.subscribe_screened`, :meth:`Bus.subscribe_topic`:
  every subscriber that decodes a topic) decodes each sample on the transport's thread
  *before* it may replace or queue behind anything: a malformed one never displaces a valid
  one, however fast garbage comes on the same key. Refusals are kept apart, one slot a key
  with a count, and reported on the loop; the valid sample arrives decoded, so the loop
  does not decode it again.

A handler that raises is logged with its traceback and counted; the subscription keeps going
(a handler bug must not take the robot down). Measure the hand-off with ``bench/handoff.py``
and ``bench/latency``.

A **direct** subscription (``subscribe(..., direct=True)``: the state aggregator's) skips the
hand-off when it can: on the opt-in lending loop (``UBF_LOOP=lending``,
:mod:`ubf_async.runtime.lending`; the default loop lends nothing) a sample that finds the loop
idle and nothing of its subscription pending is drained at once on the
transport's thread, with the loop lent to it (:mod:`ubf_async.runtime.lending`): same handler, same
order, same counters, one thread at a time, and no wake-up of the loop thread on the way — up
to :data:`DIRECT_RATE_HZ` samples a second; a flood beyond it takes the usual road and
coalesces.

A subscription with a **lane** (``subscribe_screened(..., lane=...)``, :class:`Lane`: the state
aggregator's, once a controller opened its reflex lane) skips the hand-off for the keys the
lane takes: a valid sample of such a key is delivered at once on the transport's thread,
holding ``lane.lock`` — which the drain also holds while it takes its batch and delivers it —
so the handler never runs on two threads at once, and in the order the samples came: while
a sample of that key still waits for the loop, a newer one joins it there instead of
overtaking it. A malformed sample takes the usual road (refusals are reported on the loop,
counted as before). If the loop holds the lock, the lane waits for it at most
:data:`LANE_WAIT_S`, then hands the sample to the loop (``BridgeStats.lane_busy``); a sample
a delivery itself publishes to the same subscription (a tick hook's) goes to the loop too,
never into the delivery that published it. The
handler must hand anything that belongs to the loop over with :meth:`Bus.call_on_loop`.

Samples between components of the **same** :class:`Bus` (one process) never take that detour:
a :class:`Publisher` hands them straight to the matching subscriptions of its bus, on the loop
(``loop.call_soon``), and transport subscribers are declared **remote only** (zenoh:
``allowed_origin=REMOTE``) so they only bring in samples from other buses. A sample published
on the loop is therefore handled on the loop's next iterations without waiting for a zenoh
thread to get the GIL — which is what lets a simulated robot run several times faster than
real time without its own commands arriving late in simulated time. Semantics (latest/every,
counters, handler errors) are the same for both paths.

Queries take the same road (:mod:`ubf_async.runtime.queries`): :meth:`Bus.declare_queryable`
answers each query on the event loop (the transport's callback only hands it over), and
:meth:`Bus.query` awaits the first reply without blocking the loop (zenoh's query runs in a
worker thread).
"""

from __future__ import annotations

import asyncio
import itertools
import logging
import secrets
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Generic, Protocol, TypeVar

from ubf_async.access.setup import rights
from ubf_async.clocks.clock import Clock, WallClock
from ubf_async.errors import ConfigurationError, ProtocolError
from ubf_async.net.keyexpr import intersects
from ubf_async.net.options import DEFAULT_ROBOT, ConnectionOptions, endpoint_locators
from ubf_async.net.transport import (
    Connection,
    Declaration,
    OutgoingPublisher,
    Transport,
    ZenohTransport,
)
from ubf_async.runtime import lending, queries
from ubf_async.runtime.declared import Declared
from ubf_async.runtime.queries import Queryable, QueryHandler
from ubf_async.runtime.ratelimit import TokenBucket
from ubf_async.wire.keys import Keys
from ubf_async.wire.protocol import Encoder, Message, count_malformed, decode
from ubf_async.wire.topics import INT64_MAX, Data, Topic

__all__ = ["DIRECT_BURST", "DIRECT_RATE_HZ", "DRAIN_BATCH", "LANE_WAIT_S", "BridgeStats", "Bus",
           "Lane", "Publisher", "RawPublisher", "SampleHandler", "Screen", "Subscription",
           "TopicScreen"]

log = logging.getLogger(__name__)

_monotonic_ns = time.monotonic_ns

DRAIN_BATCH = 256
"""Samples a subscription hands to its handler in one pass of the event loop."""
DIRECT_RATE_HZ = 1000.0
"""Samples per second a direct subscription may have handled on the transport's thread
(:mod:`~ubf_async.runtime.lending`), beyond a burst of :data:`DIRECT_BURST`: a robot's sensors send
a few hundred; above that — a flood — samples take the usual road and coalesce, so the
transport's threads never hold the GIL for long against the loop."""
DIRECT_BURST = 100
"""Samples a direct subscription may have handled on the transport's thread back to back,
before :data:`DIRECT_RATE_HZ` paces it."""

LANE_WAIT_S = 0.005
"""How long a sample on a lane waits for the lock the loop holds (a tick, a drain) before it
is handed to the loop instead: the loop would handle it only after that work anyway, so
waiting costs no more, and the bound keeps the transport's thread from being held long."""

SampleHandler = Callable[[str, bytes, int], None]
"""``handler(key, payload, received_ns)`` — runs on the event loop."""

T = TypeVar("T")




# ---------------------------------------------------------------------------------------------
# The bridge


@dataclass
class BridgeStats:
    received: int = 0
    delivered: int = 0
    coalesced: int = 0
    """Samples overwritten by a newer one on the same key before the loop drained them."""
    dropped: int = 0
    """Samples dropped from a full queue (``every`` mode)."""
    handler_errors: int = 0
    direct: int = 0
    """Hand-offs run on the transport's thread while the loop was idle (``direct=True``)."""
    refused: int = 0
    """Samples a screen refused and reported (screened subscriptions): they replaced nothing.
    (Refusals on a new key beyond ``max_queue`` keys waiting are counted as dropped.)"""
    lane: int = 0
    """Samples delivered on the transport's thread by the subscription's :class:`Lane`."""
    lane_waited: int = 0
    """Of those the lane took, how many found its lock held (by the loop) and waited."""
    lane_busy: int = 0
    """Samples of a lane's key handed to the loop because its lock stayed held
    :data:`LANE_WAIT_S`."""
    lane_deferred: int = 0
    """Samples of a lane's key handed to the loop because an older one of that key still
    waited there (per-key order)."""


class Screen(Protocol):
    """What a screened subscription does with each sample (:meth:`Bus.subscribe_screened`).

    :meth:`check` runs first, on the thread the transport calls back on, before the sample may
    replace a pending one (latest mode) or take a place in the queue (every mode): it must be
    pure — no shared state. :meth:`accept` and :meth:`refuse` run later on the event loop."""

    def check(self, key: str, payload: bytes) -> Any:
        """The decoded sample, handed to :meth:`accept`; raises
        :class:`~ubf_async.errors.ProtocolError` for a sample to refuse."""
        ...

    def accept(self, key: str, payload: bytes, received_ns: int, decoded: Any) -> None:
        """Handle a sample :meth:`check` passed (the newest of its key, in latest mode)."""
        ...

    def refuse(self, key: str, payload: bytes, received_ns: int, error: ProtocolError,
               count: int) -> None:
        """Report ``count`` samples on ``key`` refused since the last drain; ``payload``,
        ``received_ns`` and ``error`` are the newest of them."""
        ...


class TopicScreen(Generic[T]):
    """The screen of a subscriber of one topic: each sample decoded as ``topic`` on the
    transport's thread; a valid one handed to ``on_message(key, message, received_ns)`` on the
    loop; malformed ones counted in ``malformed`` per key
    (:func:`~ubf_async.wire.protocol.count_malformed`), and passed to ``on_error`` if given."""

    def __init__(self, topic: Topic[T], on_message: Callable[[str, Message[T], int], None],
                 malformed: dict[str, int], *,
                 on_error: Callable[[str, ProtocolError], None] | None = None) -> None:
        self.topic = topic
        self.on_message = on_message
        self.malformed = malformed
        self.on_error = on_error

    def check(self, key: str, payload: bytes) -> Message[T]:
        return decode(payload, topic=self.topic)

    def accept(self, key: str, payload: bytes, received_ns: int, decoded: Message[T]) -> None:
        self.on_message(key, decoded, received_ns)

    def refuse(self, key: str, payload: bytes, received_ns: int, error: ProtocolError,
               count: int) -> None:
        count_malformed(self.malformed, key, error, count)
        if self.on_error is not None:
            self.on_error(key, error)


class Lane(Protocol):
    """Which samples of a screened subscription are delivered on the transport's thread, and
    the lock that makes that safe (module docstring): whoever else touches what the handler
    touches holds ``lock`` too, on the loop."""

    lock: threading.RLock
    """Held around every delivery of the subscription, on the lane and in the drain."""

    def takes(self, key: str, decoded: Any) -> bool:
        """Whether this valid sample (``decoded``: what the screen's ``check`` returned) is
        delivered at once on the transport's thread; called there, without the lock."""
        ...


class _Refused:
    """The refusals on one key since the last drain: how many, and the newest."""

    __slots__ = ("count", "error", "payload", "received_ns")

    def __init__(self, payload: bytes, received_ns: int, error: ProtocolError) -> None:
        self.count = 1
        self.payload = payload
        self.received_ns = received_ns
        self.error = error


class Subscription(Declared):
    """A subscriber whose samples are delivered on the event loop (the bridge): to
    ``handler(key, payload, received_ns)``, or through ``screen`` (:class:`Screen`) for a
    screened one."""

    def __init__(
        self,
        loop: asyncio.AbstractEventLoop,
        handler: SampleHandler | None,
        *,
        latest: bool,
        max_queue: int = 1024,
        name: str = "",
        direct: bool = False,
        screen: Screen | None = None,
        lane: Lane | None = None,
    ) -> None:
        super().__init__()
        self._loop = loop
        self._check: Callable[[str, bytes], Any] | None = None
        """Runs on the transport's thread before anything pending is touched (screened)."""
        self._deliver: Callable[[str, bytes, int, Any], None]
        if screen is not None and handler is None:
            self._check, self._deliver = screen.check, screen.accept
        elif handler is not None and screen is None:
            raw = handler
            self._deliver = lambda key, payload, received_ns, _: raw(key, payload, received_ns)
        else:
            raise TypeError("a subscription takes a handler or a screen, one of them")
        self._screen = screen
        if lane is not None and screen is None:
            raise TypeError("a lane needs a screened subscription (it judges decoded samples)")
        self._lane = lane
        self._lane_thread: int | None = None
        """The thread delivering a sample on the lane now (holding its lock): a sample that
        delivery publishes to this subscription goes to the loop, not into the delivery."""
        self._latest = latest
        self._run_if_idle = lending.run_if_idle(loop) if direct else None
        """Runs the drain on the transport's thread while the loop waits (:mod:`.lending`)."""
        self._direct_budget = TokenBucket(rate_hz=DIRECT_RATE_HZ, burst=DIRECT_BURST,
                                          now_ns=_monotonic_ns())
        """Samples handled on the transport's thread (:data:`DIRECT_RATE_HZ`); used with the
        lock held."""
        self._pending_latest: dict[str, tuple[bytes, int, Any]] = {}
        self._pending_queue: deque[tuple[str, bytes, int, Any]] = deque(maxlen=max_queue)
        self._pending_refused: dict[str, _Refused] = {}
        """Refused samples by key (screened subscriptions), kept apart from the valid ones."""
        self._max_pending = max_queue
        """Distinct keys waiting in latest mode (a new key beyond them is dropped); also the
        keys with refusals waiting."""
        self._scheduled = False
        self.name = name
        self.stats = BridgeStats()

    # transport thread --------------------------------------------------------------------
    def push_from_loop(self, key: str, payload: bytes) -> None:
        """:meth:`push` for callbacks that run on the loop's own thread (in-process)."""
        self.push(key, payload, on_loop=True)

    @property
    def pending(self) -> bool:
        """Whether samples wait for a drain."""
        return self._scheduled

    def push(self, key: str, payload: bytes, *, on_loop: bool = False) -> None:
        """Hand one sample to the loop; callable from any thread, never blocks for long.

        ``on_loop=True`` (only from the loop's own thread) schedules the drain with
        ``call_soon``, skipping the thread-safe wake-up."""
        received_ns = _monotonic_ns()
        decoded: Any = None
        error: ProtocolError | None = None
        if self._check is not None:
            # Before the lock, and before anything pending is touched: garbage never
            # replaces a valid sample, and the lock is never held while decoding.
            try:
                decoded = self._check(key, payload)
            except ProtocolError as exc:
                error = exc
        lane = self._lane
        if (lane is not None and error is None and not on_loop and lane.takes(key, decoded)
                and self._on_lane(lane, key, payload, received_ns, decoded)):
            return
        self._queue(key, payload, received_ns, decoded, error, on_loop)

    def _on_lane(self, lane: Lane, key: str, payload: bytes, received_ns: int,
                 decoded: Any) -> bool:
        """Deliver one valid sample here, on the transport's thread, holding the lane's lock;
        ``False`` if it must go to the loop instead (the lock stayed held by the loop, or
        this thread is delivering on this lane already)."""
        me = threading.get_ident()
        if self._lane_thread == me:
            return False  # published from within a delivery here (a tick's hook): not inside it
        stats = self.stats
        lock = lane.lock
        waited = not lock.acquire(False)
        if waited and not lock.acquire(True, LANE_WAIT_S):
            with self._lock:
                stats.lane_busy += 1
            return False
        try:
            with self._lock:
                if self._closed:
                    return True
                if (key in self._pending_latest) if self._latest else self._pending_queue:
                    stats.lane_deferred += 1
                    deferred = True
                else:
                    deferred = False
                    stats.received += 1
                    stats.lane += 1
                    if waited:
                        stats.lane_waited += 1
            if deferred:  # queued behind its elder, still holding the lock: nothing overtakes
                self._queue(key, payload, received_ns, decoded, None, False)
                return True
            self._lane_thread = me
            try:
                self._deliver(key, payload, received_ns, decoded)
            except Exception:
                stats.handler_errors += 1
                log.exception("handler of subscription %s failed on %s (lane)", self.name, key)
            else:
                stats.delivered += 1
            finally:
                self._lane_thread = None
            return True
        finally:
            lock.release()

    def _queue(self, key: str, payload: bytes, received_ns: int, decoded: Any,
               error: ProtocolError | None, on_loop: bool) -> None:
        """Store one sample for the loop's drain and schedule it (the usual road)."""
        stats = self.stats
        with self._lock:
            if self._closed:
                return
            stats.received += 1
            if error is not None:
                refused = self._pending_refused.get(key)
                if refused is not None:
                    refused.count += 1
                    refused.payload, refused.received_ns, refused.error = (payload, received_ns,
                                                                           error)
                elif len(self._pending_refused) >= self._max_pending:
                    stats.dropped += 1  # junk keys must not grow memory either
                    return
                else:
                    self._pending_refused[key] = _Refused(payload, received_ns, error)
                stats.refused += 1
            elif self._latest:
                pending = self._pending_latest
                if key in pending:
                    stats.coalesced += 1
                elif len(pending) >= self._max_pending:
                    # A flood of distinct keys must not grow memory or the loop's next batch.
                    stats.dropped += 1
                    return
                pending[key] = (payload, received_ns, decoded)
            else:
                queue = self._pending_queue
                if len(queue) == self._max_pending:  # full: append drops the oldest
                    stats.dropped += 1
                queue.append((key, payload, received_ns, decoded))
            if self._scheduled:
                return
            self._scheduled = True
            lend = self._run_if_idle
            if on_loop or (lend is not None and not self._direct_budget.take(received_ns)):
                lend = None
        if on_loop:
            self._loop.call_soon(self._drain)
            return
        if lend is not None and lend(self._drain):
            stats.direct += 1
            return
        try:  # noqa: SIM105 — contextlib.suppress would add ≈ 0.4 µs to every hand-off
            self._loop.call_soon_threadsafe(self._drain)
        except RuntimeError:  # a closed loop: nothing left to deliver to
            pass

    # event loop --------------------------------------------------------------------------
    def _drain(self) -> None:
        lane = self._lane
        if lane is None:
            self._drain_batch()
            return
        with lane.lock:  # taken before the batch: a lane sample never overtakes one in it
            self._drain_batch()

    def _drain_batch(self) -> None:
        with self._lock:
            refused = _take_batch(self._pending_refused) if self._pending_refused else None
            if self._latest:
                pending = self._pending_latest
                if len(pending) <= DRAIN_BATCH:  # the usual case: take the whole dict
                    self._pending_latest = {}
                    batch = [(k, p, t, d) for k, (p, t, d) in pending.items()]
                else:
                    keys = list(itertools.islice(pending, DRAIN_BATCH))
                    batch = [(k, *pending.pop(k)) for k in keys]
            else:
                queue = self._pending_queue
                if len(queue) <= DRAIN_BATCH:
                    batch = list(queue)
                    queue.clear()
                else:
                    batch = [queue.popleft() for _ in range(DRAIN_BATCH)]
            more = bool(self._pending_latest or self._pending_queue or self._pending_refused)
            # With more waiting the drain stays scheduled, but yields to the loop first:
            # a flood is handled in slices, never in one pass that starves other tasks.
            self._scheduled = more
        if more:
            self._loop.call_soon(self._drain)
        if refused:
            self._report_refused(refused)
        deliver = self._deliver
        stats = self.stats
        for key, payload, received_ns, decoded in batch:
            if self._closed:
                return
            try:
                deliver(key, payload, received_ns, decoded)
            except Exception:
                stats.handler_errors += 1
                log.exception("handler of subscription %s failed on %s", self.name, key)
            else:
                stats.delivered += 1

    def _report_refused(self, refused: list[tuple[str, _Refused]]) -> None:
        screen = self._screen
        assert screen is not None  # only a screen refuses
        refuse = screen.refuse
        for key, r in refused:
            if self._closed:
                return
            try:
                refuse(key, r.payload, r.received_ns, r.error, r.count)
            except Exception:
                self.stats.handler_errors += 1
                log.exception("subscription %s failed on a refusal on %s", self.name, key)


def _take_batch(pending: dict[str, _Refused]) -> list[tuple[str, _Refused]]:
    """Up to :data:`DRAIN_BATCH` of ``pending``'s entries, oldest key first, removed from it."""
    keys = list(itertools.islice(pending, DRAIN_BATCH))
    return [(k, pending.pop(k)) for k in keys]


class _Sending:
    """What a publisher and a raw publisher share: knowing who listens on their key."""

    key: str
    _bus: Bus
    _out: OutgoingPublisher

    def has_subscribers(self) -> bool:
        """Whether a subscriber matching this key is known: on this bus, or to the transport."""
        return bool(self._bus._local_subscriptions(self.key)) or self._out.has_remote_subscribers()

    async def wait_for_subscribers(self, timeout_s: float = 5.0, *, present: bool = True) -> None:
        """Wait until a matching subscriber is known (declarations propagate asynchronously:
        a sample put before that is not delivered to it); with ``present=False``, until none
        is left. Raises TimeoutError."""
        deadline = time.monotonic() + timeout_s
        while self.has_subscribers() is not present:
            if time.monotonic() > deadline:
                raise TimeoutError(f"{'no' if present else 'still a'} subscriber for "
                                   f"{self.key} within {timeout_s}s")
            await asyncio.sleep(0.01)


class Publisher(_Sending):
    """Publishes validated messages of one schema on one key, numbering them.

    Every instance draws a random publisher identity (``pub``: 1 ≤ pub < 2**63) that goes in
    each envelope, so receivers order its samples by ``seq`` per publisher and recognise a
    restarted component (a new instance, a new ``pub``, ``seq`` from 1 again) as a new
    publisher rather than as a replay (:mod:`ubf_async.runtime.ordering`)."""

    def __init__(self, bus: Bus, key: str, schema: str, *, period_s: float | None,
                 trusted: bool = False) -> None:
        """``trusted``: what is published is built valid by construction as the topic's
        typed message, so it is not validated again on every call (:class:`Encoder`)."""
        self.key = key
        self.schema = schema
        self.period_s = period_s
        self.seq = 0
        self.pub = secrets.randbelow(INT64_MAX) + 1
        self._encoder = Encoder(schema, period_s=period_s, pub=self.pub, trusted=trusted)
        self._bus = bus
        bus.rights.check("put", key)
        self._out = bus._connection.declare_publisher(key)
        self._put = self._out.put
        self._closed = False

    def publish(self, data: Data | Mapping[str, Any], *,
                stamp_ns: int | None = None) -> tuple[int, int]:
        """Encode and send one sample (the topic's typed message, or a map of its fields,
        validated either way): to the matching subscriptions of this bus (on the loop)
        and through the transport to other buses. Returns ``(seq, stamp_ns)`` of what was sent.
        Call it on the bus's event loop."""
        bus = self._bus
        stamp = bus.clock.now_ns() if stamp_ns is None else stamp_ns
        self.seq += 1
        payload = self._encoder.encode(data, stamp_ns=stamp, seq=self.seq)
        local = bus._local_subscriptions(self.key)
        if local:
            on_loop = threading.get_ident() == bus._loop_thread
            for sub in local:
                sub.push(self.key, payload, on_loop=on_loop)
        self._put(payload)
        return self.seq, stamp

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._out.undeclare()


class RawPublisher(_Sending):
    """Puts payloads on one key as they are (:meth:`Bus.raw_publisher`)."""

    def __init__(self, bus: Bus, key: str) -> None:
        self._bus = bus
        self.key = key
        bus.rights.check("put", key)
        self._out = bus._connection.declare_publisher(key)

    def put(self, payload: bytes) -> None:
        local = self._bus._local_subscriptions(self.key)
        if local:
            on_loop = threading.get_ident() == self._bus._loop_thread
            for sub in local:
                sub.push(self.key, payload, on_loop=on_loop)
        self._out.put(payload)

    def close(self) -> None:
        self._out.undeclare()


class Bus:
    """One robot's view of the network, used from one event loop.

    The bytes move through a transport (:mod:`ubf_async.net.transport`), as an HTTP client's
    requests go through its transport: ``Bus.open(options)`` opens a zenoh session and is what
    every entry point uses; ``Bus(transport=InProcessTransport(), robot="mini")`` connects to a
    network inside the loop (unit tests: several buses on one transport see each other as
    processes do). The bus adds the same things on either: the hand-off onto the loop, same-bus
    delivery, latest/every modes, bounded queues and counted handler errors.

    Construct it on its event loop. Open with ``async with await Bus.open(options) as bus``
    or ``bus = await Bus.open(...)`` and ``await bus.aclose()`` (idempotent).
    """

    def __init__(
        self, *, transport: Transport, options: ConnectionOptions | None = None,
        robot: str | None = None, clock: Clock | None = None,
    ) -> None:
        """``options`` (their ``robot``) or ``robot`` name the robot (default
        :data:`DEFAULT_ROBOT`); ``clock`` stamps what this bus publishes (default: the wall
        clock). Raises :class:`~ubf_async.errors.ConfigurationError` for a bad robot name or
        ``robot`` contradicting ``options``."""
        if options is None:
            options = ConnectionOptions(robot=robot or DEFAULT_ROBOT)
        elif robot is not None and robot != options.robot:
            raise ConfigurationError(f"Bus: robot={robot!r} but options.robot="
                                     f"{options.robot!r}")
        try:
            self.keys = Keys(options.robot)
        except ProtocolError as exc:
            raise ConfigurationError(f"robot name: {exc}") from None
        self.options = options
        self.rights = rights(options)
        """What this process may send (secure mode: its identity's grants), checked
        before each publisher, token, queryable and query."""
        self.clock: Clock = clock or WallClock()
        self.transport = transport
        self._loop = asyncio.get_running_loop()
        self._loop_thread = threading.get_ident()
        self._subscriptions: list[Subscription] = []
        self._queryables: list[Queryable] = []
        self._local: list[tuple[str, Subscription]] = []
        self._local_by_key: dict[str, list[Subscription]] = {}
        """Which local subscriptions each published key reaches; cleared on any change."""
        self._closed = False
        self._connection: Connection = transport.connect(loop=self._loop,
                                                         pending=self._has_pending)

    @classmethod
    async def open(cls, options: ConnectionOptions, *, clock: Clock | None = None,
                   ordered: bool = False) -> Bus:
        """A bus on a zenoh session the transport opens on ``options``
        (:meth:`ZenohTransport.open <ubf_async.net.transport.ZenohTransport.open>`: what it
        raises, and listen endpoints on port 0 given a free port first, so ``bus.options.listen``
        names the ports really listened on).

        ``ordered``: samples of every key are handed to the loop in the order the sending
        session sent them (:class:`~ubf_async.net.transport.ZenohConnection`): for the processes
        of a lockstep run."""
        transport = await ZenohTransport.open(options, ordered=ordered)
        assert transport.options is not None  # (open sets them)
        return cls(transport=transport, options=transport.options, clock=clock)

    @property
    def robot(self) -> str:
        return self.options.robot

    @property
    def connection(self) -> Connection:
        """This bus's connection on its transport (:class:`~ubf_async.net.transport.Connection`):
        for a service speaking another protocol on the same network beside the bus (the ROS 2
        bridge); what it declares there bypasses the bus (no hand-off, no rights checked)."""
        return self._connection

    def _has_pending(self) -> bool:
        """Whether a subscription holds undelivered samples or a queryable unanswered
        queries (what :meth:`InProcessTransport.settle` waits for)."""
        return (any(sub.pending for sub in self._subscriptions)
                or any(q.pending for q in self._queryables))

    def call_on_loop(self, callback: Callable[..., object], *args: Any) -> None:
        """Run ``callback(*args)`` now on the loop's thread; from any other thread (a lane),
        hand it to the loop (``call_soon_threadsafe``) without waiting for it: what a handler
        on a lane does with whatever belongs to the loop (a future, an asyncio event)."""
        if threading.get_ident() == self._loop_thread:
            callback(*args)
            return
        try:  # noqa: SIM105 — the lane's path: kept as cheap as the bridge's own
            self._loop.call_soon_threadsafe(callback, *args)
        except RuntimeError:  # a closed loop: nothing left to hand it to
            pass

    def _bridge_callback(self, sub: Subscription) -> Callable[[str, bytes], None]:
        return sub.push_from_loop if self._connection.callbacks_on_loop else sub.push

    def publisher(self, topic: Topic[Any] | str, *parts: str, period_s: float | None = None,
                  trusted: bool = False, **named_parts: str) -> Publisher:
        """A publisher of ``topic`` (:mod:`ubf_async.wire.topics`) on its key for this robot:
        ``bus.publisher(CAMERA, "front", period_s=0.11)``. For a schema not declared there,
        give the key and the schema name instead: ``bus.publisher(key, "my.schema")``.
        ``trusted``: see :class:`Publisher`."""
        if isinstance(topic, Topic):
            return Publisher(self, topic.key(self.keys, *parts, **named_parts), topic.schema,
                             period_s=period_s, trusted=trusted)
        if len(parts) != 1 or named_parts:
            raise TypeError("publisher(key, schema): give the key and one schema name")
        return Publisher(self, topic, parts[0], period_s=period_s, trusted=trusted)

    def raw_publisher(self, key: str) -> RawPublisher:
        """A publisher of payloads exactly as given (no encoding, no checks: a tool replaying
        recorded messages); subscribers of this bus receive them too."""
        return RawPublisher(self, key)

    def subscribe(
        self, key_expr: str, handler: SampleHandler, *, latest: bool = True,
        max_queue: int = 1024, direct: bool = False,
    ) -> Subscription:
        """Deliver samples matching ``key_expr`` to ``handler`` on the event loop, as they came
        (a subscriber of a topic wants :meth:`subscribe_topic`: garbage cannot displace its
        samples).

        ``direct=True``: on a :class:`~ubf_async.runtime.lending.LendingEventLoop` (opt-in,
        ``UBF_LOOP=lending``; the default loop lends nothing), a sample from another process
        that finds the loop idle is handled at once on the transport's thread, with the loop
        lent to it, instead of waking the loop thread (:mod:`ubf_async.runtime.lending`); for
        short handlers on a latency path."""
        return self._subscribe(key_expr, Subscription(
            self._loop, handler, latest=latest, max_queue=max_queue, name=key_expr,
            direct=direct))

    def subscribe_screened(
        self, key_expr: str, screen: Screen, *, latest: bool = True, max_queue: int = 1024,
        direct: bool = False, lane: Lane | None = None,
    ) -> Subscription:
        """:meth:`subscribe`, with every sample passed through ``screen`` (:class:`Screen`)
        before it may replace or queue behind anything: the newest *valid* sample per key is
        what the loop gets, at any rate of garbage on the key. ``lane``: the valid samples
        it takes are delivered on the transport's thread instead (module docstring)."""
        return self._subscribe(key_expr, Subscription(
            self._loop, None, latest=latest, max_queue=max_queue, name=key_expr,
            direct=direct, screen=screen, lane=lane))

    def subscribe_topic(
        self, key_expr: str, topic: Topic[T],
        on_message: Callable[[str, Message[T], int], None], malformed: dict[str, int], *,
        latest: bool = True, max_queue: int = 1024, direct: bool = False,
    ) -> Subscription:
        """Deliver ``topic``'s samples matching ``key_expr`` decoded, to
        ``on_message(key, message, received_ns)`` on the loop; malformed ones are counted in
        ``malformed`` per key and never displace a valid one (:class:`TopicScreen`)."""
        return self.subscribe_screened(key_expr, TopicScreen(topic, on_message, malformed),
                                       latest=latest, max_queue=max_queue, direct=direct)

    def declare_key(self, key: str) -> Declaration:
        """Tell the network that samples on the concrete ``key``, heard by a subscription of
        this bus, come often and want delivering fast (the reflex lane's sensors):
        :meth:`Connection.declare_key <ubf_async.net.transport.Connection.declare_key>`.
        ``undeclare()`` it once they no longer do."""
        return self._connection.declare_key(key)

    def _subscribe(self, key_expr: str, sub: Subscription) -> Subscription:
        # Samples from this bus arrive through Publisher.publish instead (module docstring).
        sub._declaration = self._connection.declare_subscriber(key_expr,
                                                               self._bridge_callback(sub))
        sub._on_close = self._forget
        self._subscriptions.append(sub)
        self._local.append((key_expr, sub))
        self._local_by_key.clear()
        return sub

    def _forget(self, sub: Subscription) -> None:
        """Drop a closed subscription, so a bus that outlives many component restarts does
        not keep every subscription it ever made."""
        if sub in self._subscriptions:
            self._subscriptions.remove(sub)
        if any(s is sub for _, s in self._local):
            self._local = [(expr, s) for expr, s in self._local if s is not sub]
            self._local_by_key.clear()

    def _local_subscriptions(self, key: str) -> list[Subscription]:
        """The open subscriptions of this bus whose key expression matches ``key``."""
        subs = self._local_by_key.get(key)
        if subs is None:
            subs = [sub for sub_expr, sub in self._local if intersects(sub_expr, key)]
            self._local_by_key[key] = subs
        return subs

    def declare_token(self, key: str) -> Declaration:
        """A liveliness token on ``key``; ``token.undeclare()`` (or closing the bus) ends it."""
        self.rights.check("liveliness_token", key)
        return self._connection.declare_token(key)

    def watch_liveliness(
        self, key_expr: str, on_change: Callable[[str, bool], None]
    ) -> Subscription:
        """Call ``on_change(key, alive)`` on the loop for tokens appearing/vanishing,
        starting with those alive now."""

        def handler(key: str, payload: bytes, received_ns: int) -> None:
            on_change(key, payload == b"+")

        sub = Subscription(self._loop, handler, latest=False, name=f"liveliness {key_expr}")
        push = self._bridge_callback(sub)

        def on_token(key: str, alive: bool) -> None:
            # The token's kind travels in the payload slot of the generic bridge.
            push(key, b"+" if alive else b"-")

        sub._declaration = self._connection.declare_liveliness_subscriber(key_expr, on_token)
        sub._on_close = self._forget
        self._subscriptions.append(sub)
        return sub

    async def alive_tokens(self, key_expr: str, *, timeout_s: float = 2.0) -> list[str]:
        """Keys of the liveliness tokens currently alive under ``key_expr``."""
        return await self._connection.liveliness_get(key_expr, timeout_s=timeout_s)

    def declare_queryable(
        self, key: str, handler: QueryHandler, *, max_pending: int = 64
    ) -> Queryable:
        """Answer queries on ``key`` (a concrete key) with ``handler(key, payload) -> reply``,
        called on the event loop; queries from this bus are answered too."""
        self.rights.check("declare_queryable", key)
        queryable = Queryable(self._loop, key, handler, max_pending=max_pending,
                              callbacks_on_loop=self._connection.callbacks_on_loop)
        queryable._declaration = self._connection.declare_queryable(key, queryable.on_query)
        queryable._on_close = self._queryables.remove
        self._queryables.append(queryable)
        return queryable

    async def query(
        self, key: str, payload: bytes | None = None, *, timeout_s: float = 5.0
    ) -> bytes:
        """Send one query on ``key`` and return the first reply's payload.

        Raises :class:`TimeoutError` when nothing answered within ``timeout_s`` (at once when
        no queryable matching ``key`` is known), :class:`QueryError` when the queryable
        answered with an error. The loop is never blocked (zenoh's query runs in a worker
        thread), so a queryable on this same loop can answer it."""
        self.rights.check("query", key)
        return await queries.query(self._connection, key, payload, timeout_s=timeout_s)

    def reached_peers(self) -> bool:
        """Whether the transport reaches another node now (see
        :func:`ubf_async.cli.attach.wait_for_robot`)."""
        return self._connection.reached_peers()

    @property
    def closed(self) -> bool:
        """Whether :meth:`aclose` has been called (nothing can be declared any more)."""
        return self._closed

    @property
    def session_id(self) -> str | None:
        """This bus's session id on the network (zenoh's, hex), ``None`` on a transport
        without ids: what a simulator names itself by in its clock samples."""
        return self._connection.session_id()

    async def connected_sessions(self) -> frozenset[str]:
        """The ids of the sessions at this bus's ``connect`` endpoints now — the robot it
        attached to (empty when it connected to none, or on a transport without links). Other
        sessions the bus reaches through them (zenoh's gossip) are not among them."""
        if not self.options.connect:
            return frozenset()
        endpoints = self.options.connect

        def locators() -> set[str]:  # (a host name is resolved: in a worker thread)
            return {locator for endpoint in endpoints for locator in endpoint_locators(endpoint)}

        return self._connection.sessions_at(await asyncio.to_thread(locators))

    async def aclose(self) -> None:
        """Undeclare everything and close the connection (the zenoh session); idempotent."""
        if self._closed:
            return
        self._closed = True
        for sub in list(self._subscriptions):
            sub.close()
        for queryable in list(self._queryables):
            queryable.close()
        await self._connection.aclose()

    async def __aenter__(self) -> Bus:
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.aclose()
