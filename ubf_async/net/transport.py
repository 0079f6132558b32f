"""The transport seam: what a :class:`~ubf_async.runtime.bus.Bus` needs from the middleware that
moves its bytes, and zenoh's implementation of it.

A :class:`Transport` is the network (think: a zenoh router and everything connected to it); a
:class:`Connection` is one bus's session on it, made by :meth:`Transport.connect`. A bus never
calls zenoh itself: it declares publishers, subscribers, liveliness tokens and queryables on its
connection, and everything it adds on top — the hand-off onto the event loop, latest/every
delivery, coalescing, bounded queues, handler errors, same-bus delivery — is the same whatever
the transport (see :mod:`ubf_async.runtime.bus`).

* :class:`ZenohTransport` opens and owns one ``zenoh.Session`` (:meth:`ZenohTransport.open`,
  what :meth:`Bus.open <ubf_async.runtime.bus.Bus.open>` calls) and, for a peer with
  ``connect`` endpoints, watches them (:func:`watch_connect_endpoints`); its callbacks run on
  zenoh's threads. Closing the bus's connection closes the session.
* The in-process transport, a network inside one event loop for unit tests, is
  :mod:`ubf_async.net.inprocess`; key expressions in pure Python, :mod:`ubf_async.net.keyexpr`.

Nothing outside :mod:`ubf_async.net` imports zenoh (a contract of ``lint-imports``): a service
speaking another protocol over the same session — the ROS 2 bridge, rmw_zenoh's attachments —
declares through the :class:`Connection` too (:meth:`Connection.declare_attachment_publisher`,
:meth:`Connection.declare_attachment_subscriber`).
"""

from __future__ import annotations

import asyncio
import contextlib
import dataclasses
import json
import threading
import time
from collections.abc import Callable, Collection
from typing import Any, NamedTuple, Protocol

import zenoh

from ubf_async.errors import ConfigurationError, NoRobotError, SessionError
from ubf_async.net.connectwatch import watch_connect_endpoints
from ubf_async.net.options import ConnectionOptions, bind_free_ports, refused_error, session_error

__all__ = ["CALLBACK_END_WAIT_S", "AsyncDeclaration", "AttachmentCallback", "AttachmentPublisher",
           "CallbackEnd", "Connection", "Declaration", "GetResult", "IncomingQuery",
           "LivelinessCallback", "OutgoingPublisher", "SampleCallback", "Transport",
           "ZenohConnection", "ZenohTransport"]

SampleCallback = Callable[[str, bytes], None]
"""``callback(key, payload)`` — a transport's subscriber callback (see :class:`Connection`)."""
LivelinessCallback = Callable[[str, bool], None]
"""``callback(key, alive)`` — a token appeared (``True``) or vanished (``False``)."""
AttachmentCallback = Callable[[str, bytes, bytes | None], None]
"""``callback(key, payload, attachment)`` (see :meth:`Connection.declare_attachment_subscriber`)."""


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

    def declare_key(self, key: str) -> Declaration:
        """Tell the network that samples on the concrete ``key`` come to this connection
        often and that their delivery time matters (a reflex's sensor), so that a transport
        can prepare for them. What the subscriptions hear is the same with or without it."""

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

    def declare_attachment_publisher(self, key: str, *,
                                     encoding: str | None = None) -> AttachmentPublisher:
        """A publisher on the concrete ``key`` whose samples carry an attachment and, if given,
        an ``encoding`` (zenoh's name of it: ``application/cdr``) — for a service speaking
        another protocol on the same network (the ROS 2 bridge: rmw_zenoh's wire format)."""

    def declare_attachment_subscriber(self, key_expr: str,
                                      callback: AttachmentCallback) -> AsyncDeclaration:
        """Call ``callback(key, payload, attachment)`` for each sample matching ``key_expr``
        from any connection, on the transport's thread in the order samples arrive (it must be
        brief: copy and hand over). ``await declaration.aclose()`` returns once the callback
        can no longer run."""

    async def aclose(self) -> None:
        """Undeclare everything still declared and leave the network; idempotent."""


class AttachmentPublisher(Protocol):
    """A publisher whose samples carry an attachment
    (:meth:`Connection.declare_attachment_publisher`)."""

    def put(self, payload: bytes, *, attachment: bytes | None = None) -> None:
        """Send ``payload`` with ``attachment`` to every matching subscriber."""

    def undeclare(self) -> None:
        """Stop publishing; idempotent."""


class AsyncDeclaration(Declaration, Protocol):
    """A declaration whose callback may still be running after :meth:`undeclare` returns:
    :meth:`aclose` undeclares it and waits until the callback is done with."""

    async def aclose(self) -> None: ...


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


class _Redeclared:
    """A declaration a :class:`ZenohConnection` can make again on another session
    (:meth:`ZenohConnection.reopen`): ``declare(session)`` makes its zenoh entity."""

    def __init__(self, connection: ZenohConnection,
                 declare: Callable[[zenoh.Session], Any]) -> None:
        self._connection = connection
        self._declare = declare
        self._entity = declare(connection.session)
        connection.live.add(self)

    def pause(self) -> None:
        """The session is about to close: nothing may be sent until :meth:`rebind`."""

    def rebind(self, session: zenoh.Session) -> None:
        """Declare it again on ``session`` (the old entity went with the old session)."""
        self._entity = self._declare(session)

    def undeclare(self) -> None:
        self._connection.live.discard(self)
        with contextlib.suppress(zenoh.ZError):  # already undeclared, or the session closed
            self._entity.undeclare()


class _ZenohDeclaration(_Redeclared):
    pass


class _ZenohLivelinessSubscriber(_Redeclared):
    """A liveliness subscriber that, across a :meth:`~ZenohConnection.reopen`, says every
    token it had seen vanish (every link went with the old session: the remote ones did), then
    hears the tokens alive on the new session (``history``) again."""

    def __init__(self, connection: ZenohConnection, key_expr: str,
                 callback: LivelinessCallback) -> None:
        self._alive: set[str] = set()
        self._callback = callback

        def on_sample(sample: zenoh.Sample) -> None:
            key, alive = str(sample.key_expr), sample.kind == zenoh.SampleKind.PUT
            (self._alive.add if alive else self._alive.discard)(key)
            callback(key, alive)

        super().__init__(connection, lambda session: session.liveliness().declare_subscriber(
            key_expr, connection.handler(on_sample), history=True))

    def rebind(self, session: zenoh.Session) -> None:
        for key in sorted(self._alive):
            self._callback(key, False)
        self._alive.clear()
        super().rebind(session)


class _ZenohKeyDeclaration(_Redeclared):
    def __init__(self, connection: ZenohConnection, key: str) -> None:
        self._session: zenoh.Session | None = None

        def declare(session: zenoh.Session) -> Any:
            self._session = session
            return session.declare_keyexpr(key)

        super().__init__(connection, declare)

    def undeclare(self) -> None:
        self._connection.live.discard(self)
        session, self._session = self._session, None
        if session is not None:
            with contextlib.suppress(zenoh.ZError):  # the session closed (and took it along)
                session.undeclare(self._entity)


def _not_sent(payload: bytes, **_: Any) -> None:
    """A publisher's ``put`` while its session is being re-opened: there is nowhere to send."""


class _ZenohPublisher(_Redeclared):
    def __init__(self, connection: ZenohConnection, key: str) -> None:
        self._send: Callable[[bytes], None] = _not_sent
        """zenoh's own ``put`` of the publisher on the current session (bound again by a
        :meth:`~ZenohConnection.reopen`; nothing while the session is swapped)."""
        self._matching = False
        """Kept by a matching listener: asking zenoh (``matching_status``) costs ≈ 45 µs on an
        idle 2-core host, and the controller asks on every tick (its trace's subscribers)."""
        self.listener: Any = None
        """Its matching listener, undeclared with it."""

        def declare(session: zenoh.Session) -> Any:
            publisher = session.declare_publisher(key)
            # On zenoh's thread: it only stores a bool (no Python thread for each publisher).
            self.listener = publisher.declare_matching_listener(
                connection.handler(self.matched, on_zenoh_thread=True))
            connection.listeners.append(self.listener)
            self._send = publisher.put
            return publisher

        super().__init__(connection, declare)

    def put(self, payload: bytes) -> None:
        # (callers bind this method once; it follows the session through a reopen)
        self._send(payload)

    def matched(self, status: zenoh.MatchingStatus) -> None:
        """The matching listener's callback (zenoh calls it at once with the current status,
        then on every change)."""
        self._matching = status.matching

    def has_remote_subscribers(self) -> bool:
        return self._matching

    def pause(self) -> None:
        self._send = _not_sent
        self._matching = False

    def undeclare(self) -> None:
        self._connection.live.discard(self)
        with contextlib.suppress(zenoh.ZError):
            if self.listener is not None:
                self.listener.undeclare()
            self._entity.undeclare()


class _ZenohAttachmentPublisher(_Redeclared):
    def __init__(self, connection: ZenohConnection, key: str, encoding: str | None) -> None:
        self._paused = False
        super().__init__(connection, lambda session: session.declare_publisher(
            key, encoding=None if encoding is None else zenoh.Encoding(encoding)))

    def put(self, payload: bytes, *, attachment: bytes | None = None) -> None:
        if not self._paused:
            self._entity.put(payload, attachment=attachment)

    def pause(self) -> None:
        self._paused = True

    def rebind(self, session: zenoh.Session) -> None:
        super().rebind(session)
        self._paused = False


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


class _ZenohCallbackDeclaration(_Redeclared):
    """A declaration with its callback's end to wait for (:meth:`aclose`)."""

    def __init__(self, connection: ZenohConnection,
                 declare: Callable[[zenoh.Session], tuple[Any, CallbackEnd]]) -> None:
        self._end: CallbackEnd | None = None

        def declared(session: zenoh.Session) -> Any:
            entity, self._end = declare(session)
            return entity

        super().__init__(connection, declared)

    async def aclose(self) -> None:
        self.undeclare()
        end = self._end
        if end is not None and not end.dropped.is_set():
            await asyncio.to_thread(end.wait, time.monotonic() + CALLBACK_END_WAIT_S)


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
    :mod:`ubf_async.clocks.lockstep`). The callbacks only copy and hand over, so zenoh's thread
    is held briefly.

    Either way a callback can still be running, or about to run, when ``session.close()``
    returns (a callback thread ends once its channel is dropped; a zenoh thread may be
    mid-call). :meth:`aclose` waits until each declaration's callback is done with
    (:class:`CallbackEnd`), so no thread enters Python from zenoh while the interpreter
    exits — which on Python 3.11 aborts the process ("FATAL: exception not rethrown")."""

    callbacks_on_loop = False

    def __init__(self, session: zenoh.Session, *, ordered: bool = False) -> None:
        self.session = session
        self.ordered = ordered
        self._callback_ends: list[CallbackEnd] = []
        self.connect_watch: asyncio.Task[None] | None = None
        """The watch of a peer's ``connect`` endpoints (:class:`ZenohTransport`), cancelled
        on :meth:`aclose`."""
        self.listeners: list[Any] = []
        """Each publisher's matching listener and the link listener (undeclared before the
        session closes)."""
        self.live: set[_Redeclared] = set()
        """Every declaration not undeclared yet: what :meth:`reopen` declares again."""
        self._lock = threading.RLock()
        """Held while declaring, and through a :meth:`reopen`: a declaration made meanwhile
        waits for the new session (a fraction of a second, only when the set-up changed)."""

    def handler(self, callback: Callable[[Any], None], *,
                on_zenoh_thread: bool | None = None) -> Any:
        """A zenoh handler for ``callback`` (:class:`CallbackEnd`), its end kept for
        :meth:`aclose`."""
        self._callback_ends = [e for e in self._callback_ends if not e.finished()]
        handler, end = CallbackEnd.handler(
            callback, on_zenoh_thread=self.ordered if on_zenoh_thread is None else on_zenoh_thread)
        self._callback_ends.append(end)
        return handler

    def declare_publisher(self, key: str) -> OutgoingPublisher:
        with self._lock:
            return _ZenohPublisher(self, key)

    def declare_subscriber(self, key_expr: str, callback: SampleCallback) -> Declaration:
        def on_sample(sample: zenoh.Sample) -> None:
            callback(str(sample.key_expr), sample.payload.to_bytes())

        with self._lock:
            return _ZenohDeclaration(self, lambda session: session.declare_subscriber(
                key_expr, self.handler(on_sample), allowed_origin=zenoh.Locality.REMOTE))

    def declare_key(self, key: str) -> Declaration:
        # A peer sends a sample on a key this session declared under the declaration's id,
        # and zenoh delivers it through the subscribers it matched once, at the declaration.
        # Any other sample (a wildcard subscriber's, as the aggregator's) comes as a key string
        # that the session parses and matches against each of its subscribers on every
        # delivery: 20-45 us more on the reflex path of a 2-core host (docs/latency.md).
        with self._lock:
            return _ZenohKeyDeclaration(self, key)

    def declare_token(self, key: str) -> Declaration:
        with self._lock:
            return _ZenohDeclaration(
                self, lambda session: session.liveliness().declare_token(key))

    def declare_liveliness_subscriber(
        self, key_expr: str, callback: LivelinessCallback
    ) -> Declaration:
        with self._lock:
            return _ZenohLivelinessSubscriber(self, key_expr, callback)

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

        with self._lock:
            return _ZenohDeclaration(self, lambda session: session.declare_queryable(
                key, self.handler(on_query)))

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

    def link_changes(self, loop: asyncio.AbstractEventLoop) -> asyncio.Event:
        """An event set (on ``loop``) whenever a link of the session comes or goes (zenoh's
        link events; the listener goes with the session)."""
        changed = asyncio.Event()

        def on_link(event: zenoh.LinkEvent) -> None:  # on a zenoh thread
            with contextlib.suppress(RuntimeError):  # the loop is closing
                loop.call_soon_threadsafe(changed.set)

        def declare(session: zenoh.Session) -> Any:
            listener = session.info.declare_link_events_listener(self.handler(on_link))
            self.listeners.append(listener)
            return listener

        with self._lock:
            _ZenohDeclaration(self, declare)
        return changed

    def declare_attachment_publisher(self, key: str, *,
                                     encoding: str | None = None) -> AttachmentPublisher:
        with self._lock:
            return _ZenohAttachmentPublisher(self, key, encoding)

    def declare_attachment_subscriber(self, key_expr: str,
                                      callback: AttachmentCallback) -> AsyncDeclaration:
        def on_sample(sample: zenoh.Sample) -> None:
            attachment = sample.attachment
            callback(str(sample.key_expr), sample.payload.to_bytes(),
                     None if attachment is None else attachment.to_bytes())

        def declare(session: zenoh.Session) -> tuple[Any, CallbackEnd]:
            # On zenoh's own thread, whatever ``ordered`` says: the callback only copies and
            # hands over. Its end is waited for by the declaration's aclose, not the session's.
            handler, end = CallbackEnd.handler(on_sample, on_zenoh_thread=True)
            return session.declare_subscriber(key_expr, handler), end

        with self._lock:
            return _ZenohCallbackDeclaration(self, declare)

    async def reopen(self, config: zenoh.Config) -> None:
        """Close the session and open another on ``config`` with the same zenoh id (peers
        following this session's clock samples keep following them), and declare on it
        everything declared now; meanwhile publishers send nothing. Every link goes with the
        old session: a peer or client comes back only if ``config`` lets it in — how a change
        of the secure set-up (a revoked or rotated identity) takes effect without restarting
        the process (:func:`ubf_async.net.secure.watch_setup`). Raises
        :class:`~ubf_async.errors.SessionError` when the new session cannot be opened (the
        process is then off the network, and says so)."""
        # A future, not a task: a cancellation must not leave the swap half done.
        swapping = asyncio.get_running_loop().run_in_executor(None, self._reopen, config)
        await asyncio.shield(swapping)

    def _reopen(self, config: zenoh.Config) -> None:
        with self._lock:
            live = list(self.live)
            for declaration in live:
                declaration.pause()
            old = self.session
            config.insert_json5("id", json.dumps(str(old.zid())))
            self._close_session()
            self.listeners.clear()
            self.session = _open_again(config)
            for declaration in live:
                if declaration in self.live:  # (not undeclared meanwhile)
                    declaration.rebind(self.session)

    def _close_session(self) -> None:
        # Listeners first, as the bus undeclares its own first: the session's closing changes
        # links and matching, and their callbacks must not run into the interpreter's exit.
        for listener in self.listeners:
            with contextlib.suppress(zenoh.ZError):
                listener.undeclare()
        self.session.close()
        deadline = time.monotonic() + CALLBACK_END_WAIT_S
        for end in self._callback_ends:
            end.wait(deadline)

    async def aclose(self) -> None:
        """Close the session; returns once it is closed and every callback is done with — also
        when cancelled meanwhile (a stop signal during a program's end, a bounded step left
        behind), which is raised then. A close cut short would go on in a worker thread that
        the process does not wait for, and a thread still in zenoh while the interpreter
        finalizes aborts the process ("FATAL: exception not rethrown"). Its time is bounded by
        zenoh's close and :data:`CALLBACK_END_WAIT_S`."""
        if self.connect_watch is not None:
            self.connect_watch.cancel()
        # A future, not a task: no cancellation (asyncio.Runner's of every task included)
        # can end it while its thread is still closing.
        closing = asyncio.get_running_loop().run_in_executor(None, self._close)
        cancelled = False
        while not closing.done():
            try:
                await asyncio.wait({closing})
            except asyncio.CancelledError:
                cancelled = True
        if cancelled:
            closing.exception()  # (retrieved: the cancellation is what is raised)
            raise asyncio.CancelledError
        closing.result()

    def _close(self) -> None:
        with self._lock:
            self._close_session()


REOPEN_ATTEMPTS_S = (0.0, 0.1, 0.3, 1.0)
"""When re-opening a session tries to open it (the old one's listeners may take a moment to
let go of their ports)."""


def _open_again(config: zenoh.Config) -> zenoh.Session:
    error: zenoh.ZError | None = None
    for delay in REOPEN_ATTEMPTS_S:
        time.sleep(delay)
        try:
            return zenoh.open(config)
        except zenoh.ZError as exc:
            error = exc
    raise SessionError(f"the session could not be opened again: {error}")


class ZenohTransport:
    """One zenoh session, carrying one bus: :meth:`open` opens it, and closing the bus's
    connection closes it."""

    def __init__(self, session: zenoh.Session, *, ordered: bool = False,
                 options: ConnectionOptions | None = None) -> None:
        """``ordered``: see :class:`ZenohConnection`; ``options``: what the session was opened
        with (a peer's ``connect`` endpoints are watched, :func:`watch_connect_endpoints`)."""
        self.session = session
        self.ordered = ordered
        self.options = options
        self._connection: ZenohConnection | None = None

    @classmethod
    async def open(cls, options: ConnectionOptions, *, ordered: bool = False) -> ZenohTransport:
        """Open a zenoh session on ``options`` (in a worker thread: opening can take a while).

        Listen endpoints on port 0 get a free port first (:func:`bind_free_ports`), so
        ``transport.options.listen`` names the ports really listened on. Raises
        :class:`~ubf_async.errors.ConfigurationError` for a configuration zenoh refuses, and
        :class:`SessionError` with a one-line message (:class:`PortInUseError` for a port
        taken, :class:`NoRobotError` when nothing answers a ``client``,
        :class:`RefusedError` when something there refuses it)."""
        options = dataclasses.replace(options, listen=bind_free_ports(options.listen))
        config = options.zenoh_config()
        try:
            session = await asyncio.to_thread(zenoh.open, config)
        except zenoh.ZError as exc:
            error = session_error(options, exc)
            if isinstance(error, NoRobotError):  # or something there refused us
                refused = await asyncio.to_thread(refused_error, options)
                raise (refused or error) from None
            raise error from None
        return cls(session, ordered=ordered, options=options)

    def connect(
        self, *, loop: asyncio.AbstractEventLoop, pending: Callable[[], bool] | None = None
    ) -> ZenohConnection:
        if self._connection is not None:
            raise ConfigurationError("a ZenohTransport carries one bus: open another zenoh "
                                     "session (Bus.open) for another bus")
        connection = self._connection = ZenohConnection(self.session, ordered=self.ordered)
        options = self.options
        if options is not None and options.mode == "peer" and options.connect:
            # A client fails to open when nothing answers; a peer opens all the same and
            # zenoh keeps trying in the background: say so, as a robot should.
            changed = connection.link_changes(loop)
            connection.connect_watch = loop.create_task(
                watch_connect_endpoints(connection.link_destinations, changed,
                                        options.connect), name="ubf-connect-watch")
        return connection

    async def reopen(self) -> None:
        """Re-open the bus's session on its options as they read now
        (:meth:`ZenohConnection.reopen`): a secure set-up's files are read again. Raises
        :class:`~ubf_async.errors.ConfigurationError` for a set-up that no longer reads (the
        session is then left as it was), :class:`~ubf_async.errors.SessionError` when the new
        session cannot be opened."""
        if self._connection is None or self.options is None:
            raise ConfigurationError("reopen: no bus on this transport yet")
        config = await asyncio.to_thread(self.options.zenoh_config)  # (reads files)
        await self._connection.reopen(config)
        self.session = self._connection.session
