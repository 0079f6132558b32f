"""The in-process transport under real buses: samples, liveliness, queries, the bridge's
semantics, and :meth:`InProcessTransport.settle` — no zenoh session, no threads, no sleeps."""

from __future__ import annotations

import asyncio
import threading

import pytest

from ubf_async.errors import ConfigurationError, KeyExprError, QueryError, SettleError
from ubf_async.net.inprocess import InProcessTransport
from ubf_async.net.options import ConnectionOptions
from ubf_async.runtime.bus import DRAIN_BATCH, Bus
from ubf_async.wire.protocol import decode

RANGE = {"range_mm": 420, "status": "ok"}


class Seen:
    def __init__(self) -> None:
        self.samples: list[tuple[str, int]] = []
        self.threads: set[int] = set()

    def __call__(self, key: str, payload: bytes, received_ns: int) -> None:
        self.samples.append((key, decode(payload).seq))
        self.threads.add(threading.get_ident())


@pytest.mark.asyncio
async def test_samples_cross_buses_once_and_on_the_loop() -> None:
    net = InProcessTransport()
    robot, device = Bus(transport=net, robot="r1"), Bus(transport=net, robot="r1")
    on_robot, on_device = Seen(), Seen()
    robot.subscribe("ubf/r1/sensor/**", on_robot, latest=False)
    device.subscribe("ubf/r1/sensor/range/*", on_device, latest=False)
    pub = device.publisher(device.keys.sensor("range", "front"), "range")
    pub.publish(RANGE)
    pub.publish(RANGE)
    assert on_robot.samples == on_device.samples == []  # handlers run on later iterations
    await net.settle()
    key = "ubf/r1/sensor/range/front"
    assert on_robot.samples == [(key, 1), (key, 2)]  # from the other bus, through the transport
    assert on_device.samples == [(key, 1), (key, 2)]  # its own bus: the local path, not twice
    assert on_robot.threads == on_device.threads == {threading.get_ident()}
    assert robot.connection.session_id() is None  # no zenoh session under it
    await robot.aclose()
    await device.aclose()


@pytest.mark.asyncio
async def test_latest_mode_coalesces_and_every_mode_bounds_its_queue() -> None:
    net = InProcessTransport()
    robot, device = Bus(transport=net), Bus(transport=net)
    latest, every = Seen(), Seen()
    latest_sub = robot.subscribe("ubf/mini/sensor/**", latest)
    every_sub = robot.subscribe("ubf/mini/sensor/**", every, latest=False, max_queue=3)
    pub = device.publisher(device.keys.sensor("range", "front"), "range")
    for _ in range(5):
        pub.publish(RANGE)
    await net.settle()
    assert latest.samples == [("ubf/mini/sensor/range/front", 5)]
    assert latest_sub.stats.coalesced == 4
    assert [seq for _, seq in every.samples] == [3, 4, 5]
    assert every_sub.stats.dropped == 2
    assert net.pending() is False
    await robot.aclose()
    await device.aclose()


@pytest.mark.asyncio
async def test_a_flood_of_keys_is_drained_in_slices() -> None:
    net = InProcessTransport()
    robot, device = Bus(transport=net), Bus(transport=net)
    seen = Seen()
    robot.subscribe("ubf/mini/sensor/**", seen)
    pubs = [device.publisher(device.keys.sensor("junk", f"k{i}"), "range")
            for i in range(DRAIN_BATCH + 10)]
    for pub in pubs:
        pub.publish(RANGE)
    await asyncio.sleep(0)  # exactly one pass of the loop: one slice
    assert len(seen.samples) == DRAIN_BATCH
    assert net.pending()
    await net.settle()
    assert len(seen.samples) == DRAIN_BATCH + 10
    await robot.aclose()
    await device.aclose()


@pytest.mark.asyncio
async def test_a_handler_that_raises_is_counted_and_the_subscription_goes_on() -> None:
    net = InProcessTransport()
    robot, device = Bus(transport=net), Bus(transport=net)
    calls: list[int] = []

    def handler(key: str, payload: bytes, received_ns: int) -> None:
        calls.append(decode(payload).seq)
        if len(calls) == 1:
            raise RuntimeError("boom")

    sub = robot.subscribe("ubf/mini/sensor/**", handler, latest=False)
    pub = device.publisher(device.keys.sensor("range", "front"), "range")
    pub.publish(RANGE)
    await net.settle()
    pub.publish(RANGE)
    await net.settle()
    assert calls == [1, 2]
    assert (sub.stats.handler_errors, sub.stats.delivered) == (1, 1)
    await robot.aclose()
    await device.aclose()


@pytest.mark.asyncio
async def test_has_subscribers_follows_the_other_buses_declarations() -> None:
    net = InProcessTransport()
    robot, device = Bus(transport=net), Bus(transport=net)
    pub = device.publisher(device.keys.sensor("range", "front"), "range")
    assert not pub.has_subscribers()
    sub = robot.subscribe("ubf/mini/sensor/*/front", Seen())
    assert pub.has_subscribers()
    sub.close()
    assert not pub.has_subscribers()
    robot.subscribe("ubf/mini/**", Seen())
    await pub.wait_for_subscribers(timeout_s=0.0)  # known at once: no propagation delay
    await robot.aclose()
    await device.aclose()


@pytest.mark.asyncio
async def test_liveliness_history_put_delete_and_closing_a_bus() -> None:
    net = InProcessTransport()
    robot, device = Bus(transport=net), Bus(transport=net)
    motors = device.declare_token(device.keys.alive("motors"))
    changes: list[tuple[str, bool]] = []
    robot.watch_liveliness(robot.keys.all_alive, lambda k, a: changes.append((k, a)))
    own = robot.declare_token(robot.keys.alive("controller"))  # its own bus's tokens too
    device.declare_token(device.keys.alive("camera"))  # closing the bus ends it
    await net.settle()
    assert changes == [("ubf/mini/alive/motors", True), ("ubf/mini/alive/controller", True),
                       ("ubf/mini/alive/camera", True)]
    assert await robot.alive_tokens(robot.keys.all_alive) == [
        "ubf/mini/alive/camera", "ubf/mini/alive/controller", "ubf/mini/alive/motors"]
    changes.clear()
    motors.undeclare()
    motors.undeclare()  # idempotent
    await net.settle()
    assert changes == [("ubf/mini/alive/motors", False)]
    changes.clear()
    await device.aclose()  # its remaining token goes with it
    await net.settle()
    assert changes == [("ubf/mini/alive/camera", False)]
    assert await robot.alive_tokens("ubf/*/alive/*") == ["ubf/mini/alive/controller"]
    own.undeclare()
    await robot.aclose()


@pytest.mark.asyncio
async def test_two_tokens_on_one_key_vanish_with_the_last() -> None:
    net = InProcessTransport()
    a, b = Bus(transport=net), Bus(transport=net)
    changes: list[tuple[str, bool]] = []
    a.watch_liveliness(a.keys.all_alive, lambda k, alive: changes.append((k, alive)))
    first, second = a.declare_token(a.keys.alive("x")), b.declare_token(b.keys.alive("x"))
    first.undeclare()
    await net.settle()
    assert changes == [("ubf/mini/alive/x", True)]
    second.undeclare()
    await net.settle()
    assert changes == [("ubf/mini/alive/x", True), ("ubf/mini/alive/x", False)]
    await a.aclose()
    await b.aclose()


@pytest.mark.asyncio
async def test_queries_are_answered_on_the_loop_from_any_bus() -> None:
    net = InProcessTransport()
    robot, peer = Bus(transport=net), Bus(transport=net)
    threads: set[int] = set()

    def handler(key: str, payload: bytes) -> bytes:
        threads.add(threading.get_ident())
        if payload == b"boom":
            raise ValueError("bad request")
        return b"echo " + payload

    key = f"{robot.keys.prefix}/echo"
    queryable = robot.declare_queryable(key, handler)
    assert await peer.query(key, b"hi") == b"echo hi"
    assert await robot.query(key, b"local") == b"echo local"  # its own bus answers too
    with pytest.raises(QueryError, match="internal error: ValueError: bad request"):
        await peer.query(key, b"boom")
    assert await peer.query(key, b"again") == b"echo again"
    assert threads == {threading.get_ident()}
    assert (queryable.stats.answered, queryable.stats.handler_errors) == (3, 1)
    with pytest.raises(TimeoutError, match="nothing answered"):
        await peer.query(f"{robot.keys.prefix}/nobody", timeout_s=30.0)  # at once: none known
    queryable.close()
    with pytest.raises(TimeoutError):
        await peer.query(key, b"hi", timeout_s=30.0)
    await robot.aclose()
    await peer.aclose()


@pytest.mark.asyncio
async def test_a_query_nobody_finishes_times_out() -> None:
    net = InProcessTransport()
    robot, peer = Bus(transport=net), Bus(transport=net)
    held: list[object] = []
    robot._connection.declare_queryable("ubf/mini/mute", held.append)
    with pytest.raises(TimeoutError):
        await peer.query("ubf/mini/mute", timeout_s=0.01)
    assert len(held) == 1
    assert not net.pending()
    await robot.aclose()
    await peer.aclose()


@pytest.mark.asyncio
async def test_settle_waits_for_chains_and_refuses_to_wait_forever() -> None:
    net = InProcessTransport()
    a, b = Bus(transport=net), Bus(transport=net)
    ping = a.publisher("ubf/mini/sensor/range/ping", "range")
    pong = b.publisher("ubf/mini/sensor/range/pong", "range")
    hops: list[str] = []
    limit = [6]

    def on_ping(key: str, payload: bytes, received_ns: int) -> None:
        hops.append("ping")
        pong.publish(RANGE)

    def on_pong(key: str, payload: bytes, received_ns: int) -> None:
        hops.append("pong")
        if len(hops) < limit[0]:
            ping.publish(RANGE)

    b.subscribe("ubf/mini/sensor/range/ping", on_ping)
    a.subscribe("ubf/mini/sensor/range/pong", on_pong)
    ping.publish(RANGE)
    await net.settle()
    assert hops == ["ping", "pong"] * 3
    limit[0] = 10**9  # now it never stops
    ping.publish(RANGE)
    with pytest.raises(SettleError):
        await net.settle(max_iterations=200)
    limit[0] = 0
    await net.settle()
    await a.aclose()
    await b.aclose()


@pytest.mark.asyncio
async def test_construction_checks() -> None:
    net = InProcessTransport()
    with pytest.raises(ConfigurationError, match="robot"):
        Bus(transport=net, robot="a", options=ConnectionOptions(robot="b"))
    with pytest.raises(ConfigurationError, match="robot name"):
        Bus(transport=net, robot="no/slash")
    bus = Bus(transport=net, options=ConnectionOptions(robot="r2"))
    assert bus.robot == "r2" and bus.keys.prefix == "ubf/r2"
    with pytest.raises(KeyExprError):
        bus.subscribe("ubf/r2//x", Seen())
    with pytest.raises(KeyExprError):
        bus.publisher("ubf/r2/sensor/*/x", "range")
    assert not bus.reached_peers()
    other = Bus(transport=net, robot="r2")
    assert bus.reached_peers()
    await other.aclose()
    assert not bus.reached_peers()
    await bus.aclose()
    await bus.aclose()  # idempotent


@pytest.mark.asyncio
async def test_closed_subscriptions_and_queryables_are_forgotten() -> None:
    # A bus that outlives many component restarts must not keep what each restart declared.
    net = InProcessTransport()
    bus = Bus(transport=net, robot="r1")
    seen = Seen()
    for _ in range(50):
        bus.subscribe("ubf/r1/sensor/**", seen).close()
        bus.watch_liveliness("ubf/r1/alive/**", lambda key, alive: None).close()
        bus.declare_queryable("ubf/r1/tree", lambda key, payload: b"").close()
    kept = bus.subscribe("ubf/r1/sensor/**", seen, latest=False)
    assert bus._subscriptions == [kept]
    assert bus._queryables == []
    pub = bus.publisher(bus.keys.sensor("range", "front"), "range")
    pub.publish(RANGE)
    await net.settle()
    assert seen.samples == [("ubf/r1/sensor/range/front", 1)]  # once: closed ones deliver nothing
    await bus.aclose()
    await bus.aclose()
