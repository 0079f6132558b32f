"""Closing a zenoh connection cannot be cut short: a cancellation during the close (a stop
signal while a program closes its bus) is raised only once the session is closed and every
callback is done with — a close left running in a worker thread while the interpreter
finalizes aborts the process ("FATAL: exception not rethrown")."""

from __future__ import annotations

import asyncio
import threading

import pytest

from tests.conftest import zenoh_session
from ubf_async.net.options import ConnectionOptions
from ubf_async.net.transport import ZenohConnection
from ubf_async.runtime.bus import Bus


@pytest.mark.asyncio
async def test_a_close_cancelled_midway_has_closed_the_session_when_it_raises(
        endpoint: str, robot: str, monkeypatch: pytest.MonkeyPatch) -> None:
    bus = await Bus.open(ConnectionOptions(robot=robot, listen=[endpoint]))
    bus.subscribe(f"ubf/{robot}/x", lambda key, payload, received_ns: None)
    bus.watch_liveliness(f"ubf/{robot}/alive/**", lambda key, up: None)
    connection = bus.connection
    assert isinstance(connection, ZenohConnection)
    ends = list(connection._callback_ends)
    # The close held in its thread until the test lets it go (a close that takes a while).
    started, go_on = threading.Event(), threading.Event()
    close = connection._close

    def held_close() -> None:
        started.set()
        go_on.wait(30)
        close()

    monkeypatch.setattr(connection, "_close", held_close)
    closing = asyncio.create_task(bus.aclose())
    assert await asyncio.to_thread(started.wait, 30)
    closing.cancel()
    for _ in range(5):  # rounds of the loop: the cancellation delivered and caught
        await asyncio.sleep(0)
    assert not closing.done()  # still waiting for the close, cancelled or not
    go_on.set()
    with pytest.raises(asyncio.CancelledError):
        await closing
    assert zenoh_session(bus).is_closed()
    assert ends and all(end.finished() for end in ends)
