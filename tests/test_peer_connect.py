"""Issue 28, item 4: a peer connecting to nothing says so, and keeps trying as a robot should.

A ``client`` whose router does not answer already refuses to start (``no robot to connect
to``); a ``peer`` opens all the same and zenoh retries its ``connect`` endpoints in the
background — which used to be silent: ``launch --connect`` to a port nothing listens on ran to
its end, exit status 0, without a word.
"""

from __future__ import annotations

import asyncio
import socket

import pytest

from tests.conftest import eventually, free_port
from tests.remote_robot import Process
from ubf_async.net.options import ConnectionOptions, endpoint_locators
from ubf_async.runtime.bus import Bus


@pytest.mark.asyncio
async def test_a_peer_connecting_to_nothing_says_so_and_connects_when_it_answers(
    endpoint: str, robot: str
) -> None:
    """``python -m ubf_async.launch --connect`` (peer mode, the default) to a port nothing
    listens on: a warning on stderr within a few seconds, and the robot runs on; when
    something comes to listen there, it connects by itself and says so, and says so again
    when that goes away."""
    nowhere = f"tcp/127.0.0.1:{free_port()}"
    launch = Process("-m", "ubf_async.launch", "--no-sim", "--robot", robot, "--listen",
                     endpoint, "--connect", nowhere, "--quiet")
    try:
        warned = await asyncio.to_thread(launch.wait_for_line, f"nothing answers at {nowhere}",
                                         timeout_s=60)
        assert "WARNING" in warned and "retrying every second" in warned, warned
        assert launch.proc.poll() is None  # a robot runs on
        await asyncio.to_thread(launch.wait_for_line, "controller:", timeout_s=60)

        there = await Bus.open(ConnectionOptions(robot=robot, listen=[nowhere]))
        try:
            await asyncio.to_thread(launch.wait_for_line, f"connected to {nowhere} after",
                                    timeout_s=60)
            alive: set[str] = set()
            there.watch_liveliness(there.keys.all_alive,
                                   lambda key, up: alive.add(key) if up else alive.discard(key))
            await eventually(lambda: f"ubf/{robot}/alive/controller" in alive, timeout_s=60,
                             what="the robot's components, over that link")
        finally:
            await there.aclose()
        await asyncio.to_thread(launch.wait_for_line, f"lost the connection to {nowhere}",
                                timeout_s=60)
        assert launch.terminate(timeout_s=30) == 0
        warnings = [line for line in launch.lines if nowhere in line]
        assert len(warnings) == 3, warnings  # nothing answers; connected; lost
    finally:
        launch.kill()


def test_an_endpoint_is_known_by_the_addresses_its_name_resolves_to() -> None:
    """The link to ``tcp/localhost:P`` has ``tcp/127.0.0.1:P`` (or ``[::1]``) as its
    destination: both count as that endpoint; options after ``#`` are not part of it."""
    assert endpoint_locators("tcp/127.0.0.1:7447#iface=lo") == {"tcp/127.0.0.1:7447"}
    names = endpoint_locators("tcp/localhost:7447")
    addresses = {info[4][0] for info in socket.getaddrinfo("localhost", 7447)}
    assert "tcp/localhost:7447" in names
    assert ("tcp/127.0.0.1:7447" in names) == ("127.0.0.1" in addresses)
    assert endpoint_locators("unixsock-stream//tmp/sock") == {"unixsock-stream//tmp/sock"}
