"""The transport seam: what a :class:`~ubf_async.runtime.bus.Bus` needs from the middleware that
moves its bytes, and two implementations of it.

A :class:`Transport` is the network (think: a zenoh router and everything connected to it); a
:class:`Connection` is one bus's session on it, made by :meth:`Transport.connect`. A bus never
calls zenoh itself: it declares publishers, subscribers, liveliness tokens and queryables on its
connection, and everything it adds on top — the hand-off onto the event loop, latest/every
delivery, coalescing, bounded queues, handler errors, same-bus delivery — is the same whatever
the transport (see :mod:`ubf_async.runtime.bus`).

* :class:`ZenohTransport` wraps one open ``zenoh.Session`` (what :meth:`Bus.open
  <ubf_async.runtime.bus.Bus.open>` makes); its callbacks run on zenoh's threads.
* :class:`InProcessTransport` is a network inside one event loop: several buses connect to
  the same instance (as processes connect to one router) and see each other's samples, tokens
  and queryables. No zenoh session, no threads: its callbacks run on the loop, inside the call
  that caused them. ``await transport.settle()`` runs the loop until every delivery is done,
  which makes unit tests of the controller, the aggregator and remote votes deterministic.

Key expressions follow zenoh's rules for the parts ubf_async uses: chunks separated by ``/``,
``*`` is exactly one chunk, ``**`` any number of chunks (none included), a chunk starting with
``@`` is verbatim (matched only by itself). :func:`intersects` implements that in pure Python;
``tests/test_transport_keyexpr.py`` checks it against ``zenoh.KeyExpr.intersects``.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import threading
import time
from collections.abc import Callable, Collection
from dataclasses import dataclass, field
from typing import Any, NamedTuple, Protocol

import zenoh

from ubf_async.errors import ConfigurationError, UbfError

SampleCallback = Callable[[str, bytes], None]
"""``callback(key, payload)`` — a transport's subscriber callback (see :class:`Connection`)."""
LivelinessCallback = Callable[[str, bool], None]
"""``callback(key, alive)`` — a token appeared (``True``) or vanished (``False``)."""


class KeyExprError(UbfError, ValueError):
    """A key expression the in-process transport cannot route (zenoh refuses it too)."""


# ---------------------------------------------------------------------------------------------
# The interface


class Declaration(Protocol):
    """Something declared on a connection (a subscriber, a queryable, a liveliness token)."""

    def undeclare(self) -> None:
        """Stop it; idempotent, and harmless after the connection has closed."""


class OutgoingPublisher(Protocol):
    """A declared publisher on one concrete key."""

    def put(self, payload: bytes) -> None:
        """Send ``payload`` to the matching subscribers of *other* connections. Called on the
        bus's event loop; must not block (zenoh's ``put`` only queues)."""

    def has_remote_subscribers(self) -> bool:
        """Whether a subscriber matching this key is known on another connection."""

    def undeclare(self) -> None:
        """Stop publishing; idempotent."""


class IncomingQuery(Protocol):
    """A query handed to a queryable's callback. The queryable must end every query with
    :meth:`drop`, after at most one :meth:`reply` or :meth:`reply_err`."""

    key: str
    """The key expression the querier asked for."""
    payload: bytes

    def reply(self, key: str, payload: bytes) -> None: ...

    def reply_err(self, text: str) -> None: ...

    def drop(self) -> None:
        """Finish the query: the querier stops waiting for this queryable."""


class GetResult(NamedTuple):
    """What :meth:`Connection.get` brought back."""

    payload: bytes | None
    """The first successful reply's payload, ``None`` if none came."""
    errors: list[str]
    """Error replies received before it (or before the end / the timeout)."""


class Connection(Protocol):
    """One bus's session on a transport: everything :class:`~ubf_async.runtime.bus.Bus` asks of the
    middleware.

    Threads: callbacks given to ``declare_*`` run on the transport's threads when
    :attr:`callbacks_on_loop` is false (zenoh) and on the event loop's thread, inside the call
    that caused them, when it is true (in-process). Either way a callback must be quick and
    must never call back into the transport or run user code: the bus's callbacks only store
    the sample and schedule a drain on the loop. Every other method is called on the loop.
    """

    callbacks_on_loop: bool

    def declare_publisher(self, key: str) -> OutgoingPublisher:
        """A publisher on the concrete ``key``."""

    def declare_subscriber(self, key_expr: str, callback: SampleCallback) -> Declaration:
        """Call ``callback(key, payload)`` for each sample matching ``key_expr`` that another
        connection publishes — **remote only**: the bus delivers its own samples to its own
        subscriptions itself (``Publisher.publish``'s local path), so they must not come back
        through here."""

    def declare_token(self, key: str) -> Declaration:
        """A liveliness token on ``key``, alive until undeclared or the connection closes."""

    def declare_liveliness_subscriber(
        self, key_expr: str, callback: LivelinessCallback
    ) -> Declaration:
        """Call ``callback(key, alive)`` for tokens under ``key_expr`` appearing and vanishing
        on any connection (this one included), starting with those alive now (history)."""

    async def liveliness_get(self, key_expr: str, *, timeout_s: float) -> list[str]:
        """Keys of the tokens alive under ``key_expr`` now (any connection), sorted."""

    def declare_queryable(
        self, key: str, callback: Callable[[IncomingQuery], None]
    ) -> Declaration:
        """Call ``callback(query)`` for each query matching the concrete ``key``, from any
        connection (this one included)."""

    async def get(self, key: str, payload: bytes | None, *, timeout_s: float) -> GetResult:
        """Query every queryable matching ``key`` and return the first successful reply, or
        once all have finished (at once when none matches) or ``timeout_s`` has passed, the
        error replies seen. Must not block the loop."""

    def reached_peers(self) -> bool:
        """Whether another node of the network is reachable now (``wait_for_robot``)."""

    def session_id(self) -> str | None:
        """This connection's id on the network (zenoh's session id, as zenoh prints it), or
        ``None`` on a transport whose connections have none."""

    def sessions_at(self, locators: Collection[str]) -> frozenset[str]:
        """The ids of the sessions this one has a link to whose destination is one of
        ``locators`` (``tcp/127.0.0.1:7447``): those at the endpoints it connected to, routers
        left out (the sessions behind a router are not at its endpoint)."""

    async def close(self) -> None:
        """Undeclare everything still declared and leave the network; idempotent."""


class Transport(Protocol):
    """A network buses connect to: ``Bus(transport=...)`` calls :meth:`connect` once."""

    def connect(
        self, *, loop: asyncio.AbstractEventLoop, pending: Callable[[], bool] | None = None
    ) -> Connection:
        """A new connection for a bus running on ``loop``. ``pending()`` tells whether that
        bus still holds work handed to it and not yet delivered (for transports that can
        wait until the network is quiet, like :meth:`InProcessTransport.settle`)."""


# ---------------------------------------------------------------------------------------------
# zenoh


class _ZenohDeclaration:
    def __init__(self, entity: Any) -> None:
        self._entity = entity

    def undeclare(self) -> None:
        with contextlib.suppress(zenoh.ZError):  # already undeclared, or the session closed
            self._entity.undeclare()


class _ZenohPublisher:
    def __init__(self, publisher: zenoh.Publisher) -> None:
        self._publisher = publisher
        self.put: Callable[[bytes], None] = publisher.put
        """zenoh's own ``put``, bound once: no extra call on the hot path."""
        self._matching = False
        """Kept by a matching listener: asking zenoh (``matching_status``) costs ≈ 45 µs on an
        idle 2-core host, and the controller asks on every tick (its trace's subscribers)."""

    def matched(self, status: zenoh.MatchingStatus) -> None:
        """The matching listener's callback (zenoh calls it at once with the current status,
        then on every change)."""
        self._matching = status.matching

    def has_remote_subscribers(self) -> bool:
        return self._matching

    def undeclare(self) -> None:
        with contextlib.suppress(zenoh.ZError):
            self._publisher.undeclare()


class _ZenohQuery:
    """A zenoh query with its payload copied on the zenoh thread that received it."""

    __slots__ = ("_query", "key", "payload")

    def __init__(self, query: zenoh.Query) -> None:
        self._query = query
        self.key = str(query.key_expr)
        self.payload = query.payload.to_bytes() if query.payload is not None else b""

    def reply(self, key: str, payload: bytes) -> None:
        self._query.reply(key, payload)

    def reply_err(self, text: str) -> None:
        with contextlib.suppress(zenoh.ZError):
            self._query.reply_err(text.encode())

    def drop(self) -> None:
        with contextlib.suppress(zenoh.ZError):
            self._query.drop()


CALLBACK_END_WAIT_S = 2.0
"""How long closing a zenoh connection waits, at most, for its callbacks to be done with."""


class CallbackEnd:
    """When one declaration's callback can no longer enter Python: once zenoh-python has run
    its ``drop``, which it does after the declaration or the session is gone and no call is in
    flight — on the declaration's own callback thread (``own_thread``, the default
    ``indirect`` callbacks: that thread is then joined too) or, for callbacks run on zenoh's
    threads, on whichever thread let go of it last."""

    __slots__ = ("dropped", "own_thread", "thread")

    def __init__(self, *, own_thread: bool) -> None:
        self.own_thread = own_thread
        self.dropped = threading.Event()
        self.thread: threading.Thread | None = None

    def on_drop(self) -> None:
        if self.own_thread:  # (asked on one of zenoh's threads, it would make a dummy)
            self.thread = threading.current_thread()
        self.dropped.set()

    def finished(self) -> bool:
        return self.dropped.is_set() and (self.thread is None or not self.thread.is_alive())

    @classmethod
    def handler(cls, callback: Callable[[Any], None], *,
                on_zenoh_thread: bool) -> tuple[Any, CallbackEnd]:
        """A zenoh-python handler running ``callback`` — on zenoh's own threads, in the order
        samples arrive, when ``on_zenoh_thread`` (the callback must be brief), else on a
        Python thread of its own — and the end to :meth:`wait` for once it is undeclared."""
        end = cls(own_thread=not on_zenoh_thread)
        return zenoh.handlers.Callback(callback, end.on_drop, indirect=not on_zenoh_thread), end

    def wait(self, deadline: float) -> None:
        """Block until the callback is done with (:data:`CALLBACK_END_WAIT_S` at most is the
        bound callers give), or ``deadline`` (``time.monotonic()``) passes."""
        dropped = self.dropped.wait(max(0.0, deadline - time.monotonic()))
        if dropped and self.thread not in (None, threading.current_thread()):
            assert self.thread is not None
            self.thread.join(max(0.0, deadline - time.monotonic()))


class ZenohConnection:
    """A bus's connection through an open zenoh session (callbacks on zenoh's threads).

    zenoh-python runs each subscriber's callback on a Python thread of its own by default,
    so samples of two keys may be handed over in another order than they were sent.
    ``ordered``: run the callbacks on the zenoh thread that received the samples instead
    (``Callback(..., indirect=False)``), in the order a session sent them — what lockstep
    needs (an acknowledgement must not overtake the vote sent before it,
    :mod:`ubf_async.runtime.lockstep`). The callbacks only copy and hand over, so zenoh's thread
    is held briefly.

    Either way a callback can still be running, or about to run, when ``session.close()``
    returns (a callback thread ends once its channel is dropped; a zenoh thread may be
    mid-call). :meth:`close` waits until each declaration's callback is done with
    (:class:`CallbackEnd`), so no thread enters Python from zenoh while the interpreter
    exits — which on Python 3.11 aborts the process ("FATAL: exception not rethrown")."""

    callbacks_on_loop = False

    def __init__(self, session: zenoh.Session, *, ordered: bool = False) -> None:
        self.session = session
        self.ordered = ordered
        self._callback_ends: list[CallbackEnd] = []

    def _handler(self, callback: Callable[[Any], None], *,
                 on_zenoh_thread: bool | None = None) -> Any:
        self._callback_ends = [e for e in self._callback_ends if not e.finished()]
        handler, end = CallbackEnd.handler(
            callback, on_zenoh_thread=self.ordered if on_zenoh_thread is None else on_zenoh_thread)
        self._callback_ends.append(end)
        return handler

    def declare_publisher(self, key: str) -> OutgoingPublisher:
        publisher = self.session.declare_publisher(key)
        out = _ZenohPublisher(publisher)
        # On zenoh's thread: it only stores a bool (no Python thread for each publisher).
        publisher.declare_matching_listener(self._handler(out.matched, on_zenoh_thread=True))
        return out

    def declare_subscriber(self, key_expr: str, callback: SampleCallback) -> Declaration:
        def on_sample(sample: zenoh.Sample) -> None:
            callback(str(sample.key_expr), sample.payload.to_bytes())

        return _ZenohDeclaration(self.session.declare_subscriber(
            key_expr, self._handler(on_sample), allowed_origin=zenoh.Locality.REMOTE))

    def declare_token(self, key: str) -> Declaration:
        return _ZenohDeclaration(self.session.liveliness().declare_token(key))

    def declare_liveliness_subscriber(
        self, key_expr: str, callback: LivelinessCallback
    ) -> Declaration:
        def on_sample(sample: zenoh.Sample) -> None:
            callback(str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT)

        return _ZenohDeclaration(self.session.liveliness().declare_subscriber(
            key_expr, self._handler(on_sample), history=True))

    async def liveliness_get(self, key_expr: str, *, timeout_s: float) -> list[str]:
        def query() -> list[str]:
            replies = self.session.liveliness().get(key_expr, timeout=timeout_s)
            return sorted(str(r.ok.key_expr) for r in replies if r.ok is not None)

        return await asyncio.to_thread(query)

    def declare_queryable(
        self, key: str, callback: Callable[[IncomingQuery], None]
    ) -> Declaration:
        def on_query(query: zenoh.Query) -> None:
            callback(_ZenohQuery(query))

        return _ZenohDeclaration(self.session.declare_queryable(key, self._handler(on_query)))

    async def get(self, key: str, payload: bytes | None, *, timeout_s: float) -> GetResult:
        def get() -> GetResult:  # in a worker thread, so a queryable on the loop can answer
            errors: list[str] = []
            replies = self.session.get(key, payload=payload, timeout=timeout_s,
                                       consolidation=zenoh.ConsolidationMode.NONE)
            for reply in replies:
                if reply.ok is not None:
                    return GetResult(reply.ok.payload.to_bytes(), errors)
                if reply.err is not None:
                    errors.append(reply.err.payload.to_bytes().decode(errors="replace"))
            return GetResult(None, errors)

        return await asyncio.to_thread(get)

    def reached_peers(self) -> bool:
        info = self.session.info
        return bool(list(info.peers_zid()) or list(info.routers_zid()))

    def session_id(self) -> str | None:
        return str(self.session.zid())

    def sessions_at(self, locators: Collection[str]) -> frozenset[str]:
        # A router there only forwards: the robot's session is behind it, not at the endpoint.
        routers = {str(zid) for zid in self.session.info.routers_zid()}
        return frozenset(str(link.zid) for link in self.session.info.links()
                         if str(link.dst) in locators and str(link.zid) not in routers)

    def link_destinations(self) -> list[str]:
        """The remote locator of each link the session has now (``tcp/127.0.0.1:7447``): a
        link to a ``connect`` endpoint has that endpoint as its destination."""
        return [str(link.dst) for link in self.session.info.links()]

    async def close(self) -> None:
        await asyncio.to_thread(self._close)

    def _close(self) -> None:
        self.session.close()
        deadline = time.monotonic() + CALLBACK_END_WAIT_S
        for end in self._callback_ends:
            end.wait(deadline)


class ZenohTransport:
    """One open zenoh session, carrying one bus (closing the bus closes the session)."""

    def __init__(self, session: zenoh.Session, *, ordered: bool = False) -> None:
        """``ordered``: see :class:`ZenohConnection`."""
        self.session = session
        self.ordered = ordered
        self._connected = False

    def connect(
        self, *, loop: asyncio.AbstractEventLoop, pending: Callable[[], bool] | None = None
    ) -> ZenohConnection:
        if self._connected:
            raise ConfigurationError("a ZenohTransport carries one bus: open another zenoh "
                                     "session (Bus.open) for another bus")
        self._connected = True
        return ZenohConnection(self.session, ordered=self.ordered)


# ---------------------------------------------------------------------------------------------
# Key expressions, in pure Python


@functools.lru_cache(maxsize=4096)
def key_chunks(key_expr: str) -> tuple[str, ...]:
    """The chunks of ``key_expr``; :class:`KeyExprError` for one zenoh would refuse or that
    uses what this module does not implement (``$*`` sub-chunk wildcards)."""
    if not key_expr or key_expr.startswith("/") or key_expr.endswith("/"):
        raise KeyExprError(f"invalid key expression {key_expr!r}: empty, or a leading or "
                           f"trailing '/'")
    chunks = tuple(key_expr.split("/"))
    for i, chunk in enumerate(chunks):
        if not chunk:
            raise KeyExprError(f"invalid key expression {key_expr!r}: empty chunk")
        if any(c in chunk for c in "#?$"):
            raise KeyExprError(f"invalid key expression {key_expr!r}: '#', '?' and '$' are "
                               f"not supported")
        if "*" in chunk and chunk not in ("*", "**"):
            raise KeyExprError(f"invalid key expression {key_expr!r}: '*' must be a whole "
                               f"chunk")
        if chunk == "**" and i > 0 and chunks[i - 1] == "**":
            raise KeyExprError(f"invalid key expression {key_expr!r}: '**/**' is not "
                               f"canonical (write '**')")
        if chunk == "*" and i > 0 and chunks[i - 1] == "**":
            raise KeyExprError(f"invalid key expression {key_expr!r}: '**/*' is not "
                               f"canonical (write '*/**')")
    return chunks


def _chunk_meets(a: str, b: str) -> bool:
    if a == b:
        return True
    if a.startswith("@") or b.startswith("@"):
        return False  # a verbatim chunk only meets itself
    return a == "*" or b == "*"


@functools.lru_cache(maxsize=16384)
def intersects(a: str, b: str) -> bool:
    """Whether some concrete key matches both key expressions ``a`` and ``b`` (zenoh's
    ``KeyExpr.intersects``)."""
    left, right = key_chunks(a), key_chunks(b)

    @functools.cache
    def meet(i: int, j: int) -> bool:
        if i == len(left) and j == len(right):
            return True
        if i < len(left) and left[i] == "**":
            if meet(i + 1, j):
                return True
            return j < len(right) and not right[j].startswith("@") and meet(i, j + 1)
        if j < len(right) and right[j] == "**":
            if meet(i, j + 1):
                return True
            return i < len(left) and not left[i].startswith("@") and meet(i + 1, j)
        if i == len(left) or j == len(right):
            return False
        return _chunk_meets(left[i], right[j]) and meet(i + 1, j + 1)

    return meet(0, 0)


# ---------------------------------------------------------------------------------------------
# In-process


@dataclass(eq=False)
class _Entry:
    """A declaration on the in-process network: the callback, and who declared it where."""

    connection: InProcessConnection
    key_expr: str
    callback: Any
    closed: bool = False

    def undeclare(self) -> None:
        if not self.closed:
            self.connection._undeclare(self)


@dataclass(eq=False)
class _InProcessPublisher:
    connection: InProcessConnection
    key: str
    closed: bool = False

    def put(self, payload: bytes) -> None:
        if self.closed or self.connection.closed:
            return
        self.connection.transport._deliver(self.connection, self.key, payload)

    def has_remote_subscribers(self) -> bool:
        return not self.closed and any(
            entry.connection is not self.connection
            for entry in self.connection.transport._route(self.key))

    def undeclare(self) -> None:
        self.closed = True


@dataclass(eq=False)
class _Get:
    """One query in flight: resolved by the first reply, or when every queryable has dropped
    it."""

    future: asyncio.Future[GetResult]
    outstanding: int
    errors: list[str] = field(default_factory=list)

    def reply(self, payload: bytes) -> None:
        if not self.future.done():
            self.future.set_result(GetResult(payload, self.errors))

    def finish_one(self) -> None:
        self.outstanding -= 1
        if self.outstanding == 0 and not self.future.done():
            self.future.set_result(GetResult(None, self.errors))


class _InProcessQuery:
    __slots__ = ("_done", "_get", "key", "payload")

    def __init__(self, get: _Get, key: str, payload: bytes) -> None:
        self._get = get
        self._done = False
        self.key = key
        self.payload = payload

    def reply(self, key: str, payload: bytes) -> None:
        if not self._done:
            self._get.reply(payload)

    def reply_err(self, text: str) -> None:
        if not self._done:
            self._get.errors.append(text)

    def drop(self) -> None:
        if not self._done:
            self._done = True
            self._get.finish_one()


class InProcessConnection:
    """A bus's connection to an :class:`InProcessTransport` (callbacks on the loop)."""

    callbacks_on_loop = True

    def __init__(self, transport: InProcessTransport,
                 pending: Callable[[], bool] | None) -> None:
        self.transport = transport
        self.pending = pending or (lambda: False)
        self.closed = False
        self._entries: list[_Entry] = []
        self._publishers: list[_InProcessPublisher] = []

    def _declare(self, kind: str, key_expr: str, callback: Any) -> _Entry:
        if self.closed:
            raise ConfigurationError("the in-process connection is closed")
        key_chunks(key_expr)  # refuse what zenoh would refuse, at the call that made it
        entry = _Entry(self, key_expr, callback)
        self._entries.append(entry)
        self.transport._add(kind, entry)
        return entry

    def _undeclare(self, entry: _Entry) -> None:
        entry.closed = True
        with contextlib.suppress(ValueError):
            self._entries.remove(entry)
        self.transport._remove(entry)

    def declare_publisher(self, key: str) -> OutgoingPublisher:
        if self.closed:
            raise ConfigurationError("the in-process connection is closed")
        if "*" in key_chunks(key):
            raise KeyExprError(f"a publisher needs a concrete key, not {key!r}")
        publisher = _InProcessPublisher(self, key)
        self._publishers.append(publisher)
        return publisher

    def declare_subscriber(self, key_expr: str, callback: SampleCallback) -> Declaration:
        return self._declare("sub", key_expr, callback)

    def declare_token(self, key: str) -> Declaration:
        return self._declare("token", key, None)

    def declare_liveliness_subscriber(
        self, key_expr: str, callback: LivelinessCallback
    ) -> Declaration:
        return self._declare("live", key_expr, callback)

    async def liveliness_get(self, key_expr: str, *, timeout_s: float) -> list[str]:
        key_chunks(key_expr)
        return sorted(key for key in self.transport._tokens if intersects(key, key_expr))

    def declare_queryable(
        self, key: str, callback: Callable[[IncomingQuery], None]
    ) -> Declaration:
        return self._declare("queryable", key, callback)

    async def get(self, key: str, payload: bytes | None, *, timeout_s: float) -> GetResult:
        return await self.transport._get(key, payload or b"", timeout_s=timeout_s)

    def reached_peers(self) -> bool:
        return any(c is not self for c in self.transport._connections)

    def session_id(self) -> str | None:
        return None

    def sessions_at(self, locators: Collection[str]) -> frozenset[str]:
        return frozenset()  # no endpoints, no links

    async def close(self) -> None:
        if self.closed:
            return
        for publisher in self._publishers:
            publisher.closed = True
        for entry in list(self._entries):
            entry.undeclare()
        self.closed = True
        self.transport._connections.remove(self)


class SettleError(UbfError, RuntimeError):
    """:meth:`InProcessTransport.settle` found work still pending after its limit."""


class InProcessTransport:
    """A network inside one event loop: buses connected to the same instance exchange samples,
    liveliness tokens and queries as processes connected to one zenoh router would.

    Semantics kept from zenoh: a subscriber sees samples of *other* connections only (the bus
    delivers its own, see :meth:`Connection.declare_subscriber`); liveliness subscribers and
    queryables see every connection, their own included; a liveliness subscriber starts with
    the tokens alive now; closing a connection undeclares its tokens (the others see them
    vanish). Several tokens on one key count as one (it vanishes with the last).

    Everything runs on the loop, in the call that caused it: :meth:`OutgoingPublisher.put`
    calls the matching subscribers' callbacks, which for a bus store the sample and schedule
    its drain with ``loop.call_soon`` — so handlers run on the loop's next iterations, exactly
    as for samples from zenoh, but with no thread involved.
    """

    def __init__(self) -> None:
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: int | None = None
        self._connections: list[InProcessConnection] = []
        self._subs: list[_Entry] = []
        self._live: list[_Entry] = []
        self._queryables: list[_Entry] = []
        self._token_entries: list[_Entry] = []
        self._tokens: dict[str, int] = {}
        """Alive token keys and how many tokens hold each."""
        self._routes: dict[str, list[_Entry]] = {}
        """Which subscribers each published key reaches; cleared on any change."""
        self._gets: set[asyncio.Future[GetResult]] = set()

    def connect(
        self, *, loop: asyncio.AbstractEventLoop, pending: Callable[[], bool] | None = None
    ) -> InProcessConnection:
        if self._loop is None:
            self._loop = loop
            self._thread = threading.get_ident()
        elif loop is not self._loop:
            raise ConfigurationError("every bus on an InProcessTransport must run on the same "
                                     "event loop")
        connection = InProcessConnection(self, pending)
        self._connections.append(connection)
        return connection

    # -- routing (on the loop) ----------------------------------------------------------------
    def _check_thread(self) -> None:
        if threading.get_ident() != self._thread:
            raise RuntimeError("InProcessTransport used off its event loop's thread")

    def _add(self, kind: str, entry: _Entry) -> None:
        self._check_thread()
        if kind == "sub":
            self._subs.append(entry)
            self._routes.clear()
        elif kind == "live":
            self._live.append(entry)
            for key in list(self._tokens):  # history: the tokens alive now
                if intersects(key, entry.key_expr):
                    entry.callback(key, True)
        elif kind == "queryable":
            self._queryables.append(entry)
        else:
            self._token_entries.append(entry)
            count = self._tokens.get(entry.key_expr, 0)
            self._tokens[entry.key_expr] = count + 1
            if count == 0:
                self._liveliness_changed(entry.key_expr, alive=True)

    def _remove(self, entry: _Entry) -> None:
        self._check_thread()
        for entries in (self._subs, self._live, self._queryables):
            if entry in entries:
                entries.remove(entry)
                self._routes.clear()
                return
        if entry in self._token_entries:
            self._token_entries.remove(entry)
            count = self._tokens[entry.key_expr] - 1
            if count:
                self._tokens[entry.key_expr] = count
            else:
                del self._tokens[entry.key_expr]
                self._liveliness_changed(entry.key_expr, alive=False)

    def _liveliness_changed(self, key: str, *, alive: bool) -> None:
        for watcher in list(self._live):
            if intersects(key, watcher.key_expr):
                watcher.callback(key, alive)

    def _route(self, key: str) -> list[_Entry]:
        route = self._routes.get(key)
        if route is None:
            route = [entry for entry in self._subs if intersects(entry.key_expr, key)]
            self._routes[key] = route
        return route

    def _deliver(self, sender: InProcessConnection, key: str, payload: bytes) -> None:
        self._check_thread()
        for entry in self._route(key):
            if entry.connection is not sender:
                entry.callback(key, payload)

    async def _get(self, key: str, payload: bytes, *, timeout_s: float) -> GetResult:
        self._check_thread()
        key_chunks(key)
        targets = [q for q in self._queryables if intersects(q.key_expr, key)]
        if not targets:
            return GetResult(None, [])
        assert self._loop is not None
        get = _Get(self._loop.create_future(), outstanding=len(targets))
        self._gets.add(get.future)
        try:
            for queryable in targets:
                queryable.callback(_InProcessQuery(get, key, payload))
            try:
                return await asyncio.wait_for(asyncio.shield(get.future), timeout_s)
            except TimeoutError:
                return GetResult(None, list(get.errors))
        finally:
            self._gets.discard(get.future)

    # -- for tests -----------------------------------------------------------------------------
    def pending(self) -> bool:
        """Whether a bus still holds samples or queries it has not handled, or a query waits
        for its replies."""
        return bool(self._gets) or any(c.pending() for c in self._connections)

    async def settle(self, *, quiet_iterations: int = 5, max_iterations: int = 100_000) -> None:
        """Run the loop until every delivery is done: no bus holds an undelivered sample or an
        unanswered query, no query waits for replies, and that has held for
        ``quiet_iterations`` loop iterations in a row (so a task woken by a handler — an event
        it set, a future it resolved — gets to run, and what it publishes is delivered too).
        No wall-clock time is involved. Raises :class:`SettleError` if the network is still
        busy after ``max_iterations`` (something publishes forever)."""
        quiet = 0
        for _ in range(max_iterations):
            await asyncio.sleep(0)
            quiet = 0 if self.pending() else quiet + 1
            if quiet >= quiet_iterations:
                return
        raise SettleError(f"the in-process network was still busy after {max_iterations} "
                          f"loop iterations")
