"""Queries on the bus: a :class:`Queryable` answers on the event loop (the transport's callback
only hands each query over), and :func:`query` awaits the first reply without blocking the
loop (zenoh's query runs in a worker thread). :meth:`Bus.declare_queryable
<ubf_async.runtime.bus.Bus.declare_queryable>` and :meth:`Bus.query
<ubf_async.runtime.bus.Bus.query>` are the entry points.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Callable
from dataclasses import dataclass

from ubf_async.errors import QueryError
from ubf_async.net.transport import Connection, IncomingQuery
from ubf_async.runtime.declared import Declared

__all__ = ["QueryHandler", "QueryStats", "Queryable", "query"]

log = logging.getLogger(__name__)

QueryHandler = Callable[[str, bytes], bytes]
"""``handler(key, payload) -> reply payload`` — runs on the event loop (see
:meth:`Bus.declare_queryable <ubf_async.runtime.bus.Bus.declare_queryable>`)."""


@dataclass
class QueryStats:
    received: int = 0
    answered: int = 0
    refused: int = 0
    """Queries answered with an error at once because ``max_pending`` were waiting."""
    handler_errors: int = 0


class Queryable(Declared):
    """A queryable whose queries are answered on the event loop.

    The transport's callback only takes the query (its payload already copied) and schedules
    the answer on the loop (``call_soon_threadsafe`` from a zenoh thread, ``call_soon`` on the
    loop's own); the handler runs there, so what it reads or changes is never touched by a
    transport thread. Its return value is the reply; a handler that raises is logged and
    counted, and the querier gets an error reply. At most ``max_pending`` queries wait for the
    loop; more are refused with an error reply at once (a flood cannot queue up work).
    """

    def __init__(
        self, loop: asyncio.AbstractEventLoop, key: str, handler: QueryHandler, *,
        max_pending: int = 64, callbacks_on_loop: bool = False,
    ) -> None:
        super().__init__()
        self.key = key
        self._loop = loop
        self._handler = handler
        self._max_pending = max_pending
        self._on_loop = callbacks_on_loop
        self._pending = 0
        self.stats = QueryStats()

    @property
    def pending(self) -> bool:
        """Whether queries wait for the loop."""
        return self._pending > 0

    # transport thread --------------------------------------------------------------------
    def on_query(self, query: IncomingQuery) -> None:
        """The transport's callback: hand the query to the loop, never block."""
        with self._lock:
            self.stats.received += 1
            refuse = "closed" if self._closed else (
                "busy" if self._pending >= self._max_pending else "")
            if refuse:
                self.stats.refused += 1
            else:
                self._pending += 1
        if refuse:
            self._error(query, f"{self.key}: {refuse}, try again")
            return
        if self._on_loop:
            self._loop.call_soon(self._answer, query)
            return
        try:
            self._loop.call_soon_threadsafe(self._answer, query)
        except RuntimeError:  # the loop is closed: nobody will answer
            self._error(query, f"{self.key}: closed")

    @staticmethod
    def _error(query: IncomingQuery, text: str) -> None:
        query.reply_err(text)
        query.drop()

    # event loop --------------------------------------------------------------------------
    def _answer(self, query: IncomingQuery) -> None:
        with self._lock:
            self._pending -= 1
            closed = self._closed
        if closed:
            self._error(query, f"{self.key}: closed")
            return
        try:
            reply = self._handler(query.key, query.payload)
        except Exception as exc:
            self.stats.handler_errors += 1
            log.exception("handler of queryable %s failed", self.key)
            self._error(query, f"{self.key}: internal error: {type(exc).__name__}: {exc}")
            return
        try:
            query.reply(self.key, reply)
            self.stats.answered += 1
        except Exception as exc:  # the transport's error (zenoh.ZError): the querier left
            log.warning("cannot reply to a query on %s: %s", self.key, exc)
        finally:
            query.drop()


async def query(connection: Connection, key: str, payload: bytes | None, *,
                timeout_s: float) -> bytes:
    """Send one query on ``key`` through ``connection`` and return the first reply's payload
    (:meth:`Bus.query <ubf_async.runtime.bus.Bus.query>` says what it raises)."""
    answer, errors = await connection.get(key, payload, timeout_s=timeout_s)
    if answer is not None:
        return answer
    if errors:
        raise QueryError("; ".join(errors))
    raise TimeoutError(f"nothing answered a query on {key} within {timeout_s:g}s")
