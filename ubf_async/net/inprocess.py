"""The in-process transport: a network inside one event loop, for unit tests.

Several buses connect to the same :class:`InProcessTransport` (as processes connect to one
router) and see each other's samples, tokens and queryables. No zenoh session, no threads: its
callbacks run on the loop, inside the call that caused them. ``await transport.settle()`` runs
the loop until every delivery is done, which makes unit tests of the controller, the aggregator
and remote votes deterministic. The interface it implements is :mod:`ubf_async.net.transport`.
"""

from __future__ import annotations

import asyncio
import contextlib
import threading
from collections.abc import Callable, Collection
from dataclasses import dataclass, field
from typing import Any, TypeVar

from ubf_async.errors import ConfigurationError, KeyExprError, SettleError
from ubf_async.net.keyexpr import intersects, key_chunks
from ubf_async.net.transport import (
    AsyncDeclaration,
    AttachmentCallback,
    AttachmentPublisher,
    Declaration,
    GetResult,
    IncomingQuery,
    LivelinessCallback,
    OutgoingPublisher,
    SampleCallback,
)

__all__ = ["InProcessConnection", "InProcessTransport"]

_P = TypeVar("_P", bound="_InProcessPublisher")


@dataclass(eq=False)
class _Entry:
    """A declaration on the in-process network: the callback, and who declared it where."""

    connection: InProcessConnection
    key_expr: str
    callback: Any
    closed: bool = False
    attachments: bool = False
    """A subscriber of every connection's samples, called with their attachment
    (:meth:`InProcessConnection.declare_attachment_subscriber`)."""

    def undeclare(self) -> None:
        if not self.closed:
            self.connection._undeclare(self)

    async def aclose(self) -> None:
        self.undeclare()  # its callback runs on the loop: done with once undeclared


class _NothingDeclared:
    def undeclare(self) -> None:
        pass


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
class _InProcessAttachmentPublisher(_InProcessPublisher):
    def put(self, payload: bytes, *, attachment: bytes | None = None) -> None:
        if self.closed or self.connection.closed:
            return
        self.connection.transport._deliver(self.connection, self.key, payload, attachment)


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

    def _declare(self, kind: str, key_expr: str, callback: Any, *,
                 attachments: bool = False) -> _Entry:
        if self.closed:
            raise ConfigurationError("the in-process connection is closed")
        key_chunks(key_expr)  # refuse what zenoh would refuse, at the call that made it
        entry = _Entry(self, key_expr, callback, attachments=attachments)
        self._entries.append(entry)
        self.transport._add(kind, entry)
        return entry

    def _undeclare(self, entry: _Entry) -> None:
        entry.closed = True
        with contextlib.suppress(ValueError):
            self._entries.remove(entry)
        self.transport._remove(entry)

    def declare_publisher(self, key: str) -> OutgoingPublisher:
        return self._publisher(_InProcessPublisher, key)

    def declare_attachment_publisher(self, key: str, *,
                                     encoding: str | None = None) -> AttachmentPublisher:
        return self._publisher(_InProcessAttachmentPublisher, key)  # (no encodings here)

    def _publisher(self, kind: type[_P], key: str) -> _P:
        if self.closed:
            raise ConfigurationError("the in-process connection is closed")
        if "*" in key_chunks(key):
            raise KeyExprError(f"a publisher needs a concrete key, not {key!r}")
        publisher = kind(self, key)
        self._publishers.append(publisher)
        return publisher

    def declare_attachment_subscriber(self, key_expr: str,
                                      callback: AttachmentCallback) -> AsyncDeclaration:
        return self._declare("sub", key_expr, callback, attachments=True)

    def declare_subscriber(self, key_expr: str, callback: SampleCallback) -> Declaration:
        return self._declare("sub", key_expr, callback)

    def declare_key(self, key: str) -> Declaration:
        key_chunks(key)
        return _NothingDeclared()  # every delivery here is one call on the loop already

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

    async def aclose(self) -> None:
        if self.closed:
            return
        for publisher in self._publishers:
            publisher.closed = True
        for entry in list(self._entries):
            entry.undeclare()
        self.closed = True
        self.transport._connections.remove(self)


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

    def _deliver(self, sender: InProcessConnection, key: str, payload: bytes,
                 attachment: bytes | None = None) -> None:
        self._check_thread()
        for entry in self._route(key):
            if entry.attachments:  # every connection's samples, its own included
                entry.callback(key, payload, attachment)
            elif entry.connection is not sender:
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
