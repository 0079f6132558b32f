"""What a subscription and a queryable of the bus share: a declaration on the transport,
undone once."""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Self

from ubf_async.net.transport import Declaration

__all__ = ["Declared"]


class Declared:
    """What :class:`Subscription` and :class:`Queryable` share: a declaration on the
    transport, undone once on :meth:`close`, which also tells the bus (``_on_close``)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._closed = False
        self._declaration: Declaration | None = None
        self._on_close: Callable[[Self], None] | None = None

    def close(self: Self) -> None:
        """Stop delivering samples or answering queries (queries still waiting get an error
        reply); idempotent."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        if self._on_close is not None:
            self._on_close(self)
        if self._declaration is not None:
            self._declaration.undeclare()
