"""A bus's zenoh session re-opened under it (the transport's ``reopen``, what a secure robot
does when its set-up changes: tests/test_revocation.py): the same zenoh id, everything
declared made again, a peer that comes back heard again — on real sessions on loopback."""

from __future__ import annotations

import pytest

from tests.conftest import eventually
from ubf_async.net.options import ConnectionOptions
from ubf_async.net.transport import ZenohTransport
from ubf_async.runtime.bus import Bus
from ubf_async.wire.protocol import decode
from ubf_async.wire.topics import RANGE

pytestmark = pytest.mark.asyncio


async def test_after_a_reopen_everything_declared_works_again(endpoint: str, robot: str) -> None:
    robot_bus = await Bus.open(ConnectionOptions(robot=robot, listen=[endpoint]))
    peer = await Bus.open(ConnectionOptions(robot=robot, connect=[endpoint]))
    try:
        heard_by_robot: list[int] = []
        heard_by_peer: list[int] = []
        tokens: list[tuple[str, bool]] = []
        robot_bus.subscribe(RANGE.key(robot_bus.keys, "peer"),
                            lambda k, p, t: heard_by_robot.append(decode(p).seq), latest=False)
        peer.subscribe(RANGE.key(peer.keys, "robot"),
                       lambda k, p, t: heard_by_peer.append(decode(p).seq), latest=False)
        robot_bus.watch_liveliness(peer.keys.all_alive,
                                   lambda key, alive: tokens.append((key, alive)))
        token = peer.declare_token(peer.keys.alive("peer"))
        to_peer = robot_bus.publisher(RANGE, "robot")
        to_robot = peer.publisher(RANGE, "peer")
        sample = {"range_mm": 200, "status": "ok"}

        async def exchanged() -> None:
            before_robot, before_peer = len(heard_by_robot), len(heard_by_peer)

            def both() -> bool:
                to_peer.publish(sample)
                to_robot.publish(sample)
                return (len(heard_by_robot) > before_robot
                        and len(heard_by_peer) > before_peer)

            await eventually(both, timeout_s=20, what="samples both ways")

        await exchanged()
        await eventually(lambda: (peer.keys.alive("peer"), True) in tokens, timeout_s=10)
        transport = robot_bus.transport
        assert isinstance(transport, ZenohTransport)
        zid = robot_bus.session_id
        await transport.reopen()
        assert robot_bus.session_id == zid  # the same node to everyone following it
        # Every link went with the old session: the peer's token is said gone, then back when
        # the peer reconnects by itself; the subscriptions and publishers of both work again.
        await eventually(lambda: (peer.keys.alive("peer"), False) in tokens, timeout_s=10)
        await exchanged()
        await eventually(lambda: tokens[-1] == (peer.keys.alive("peer"), True), timeout_s=20,
                         what="the peer's token back")
        token.undeclare()
    finally:
        await peer.aclose()
        await robot_bus.aclose()
