"""What the clocks need of a bus: the few members of :class:`ubf_async.runtime.bus.Bus` that
following a clock, naming a sample's sender and a lockstep barrier use.

The bus stamps with a :class:`~ubf_async.clocks.clock.Clock`, so the clocks sit below it;
the followers subscribe on a bus all the same, through this protocol (the runtime's ``Bus``
has every member; mypy checks each call that passes one). Nothing here imports the runtime.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol, TypeVar

from ubf_async.clocks.clock import Clock
from ubf_async.wire.keys import Keys
from ubf_async.wire.protocol import Message
from ubf_async.wire.topics import Topic

__all__ = ["ClockBus", "Closing"]

T = TypeVar("T")


class Closing(Protocol):
    """A subscription: :meth:`close` stops it (idempotent)."""

    def close(self) -> None: ...


class ClockBus(Protocol):
    """The members of a bus the clocks use."""

    keys: Keys
    clock: Clock

    @property
    def robot(self) -> str: ...

    @property
    def closed(self) -> bool: ...

    def subscribe(self, key_expr: str, handler: Callable[[str, bytes, int], None], *,
                  latest: bool = ..., max_queue: int = ..., direct: bool = ...) -> Closing: ...

    def subscribe_topic(self, key_expr: str, topic: Topic[T],
                        on_message: Callable[[str, Message[T], int], None],
                        malformed: dict[str, int], *, latest: bool = ..., max_queue: int = ...,
                        direct: bool = ...) -> Closing: ...

    def watch_liveliness(self, key_expr: str,
                         on_change: Callable[[str, bool], None]) -> Closing: ...

    async def connected_sessions(self) -> frozenset[str]: ...
