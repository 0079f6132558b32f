"""A key declared to the network (``Bus.declare_key``) changes how zenoh delivers its samples,
never what is delivered (docs/latency.md, "The reflex at the Python floor").

Real zenoh sessions on a loopback endpoint. A peer sends to a wildcard subscriber by key
string until the receiving session declares the key; from then on it sends under the session's
numeric id, until the key is undeclared. What must hold, for a small sample and for one large
enough to be fragmented, and for every wildcard subscription of the session (the aggregator's
``sensor/*/*`` and a live view's ``**``): nothing is lost, duplicated or reordered before,
across or after the declaration and the undeclaration — even with samples in flight at each.
The aggregator declares the keys of the robot's own sources that take its reflex lane.
"""

from __future__ import annotations

from typing import Any

import pytest
import zenoh

from tests.conftest import eventually, zenoh_session
from ubf_async import Action, Behavior, State
from ubf_async.net.inprocess import InProcessTransport
from ubf_async.net.transport import Declaration
from ubf_async.runtime.aggregator import StateAggregator
from ubf_async.runtime.bus import Bus, Subscription
from ubf_async.runtime.controller import Controller

SMALL = b"r" * 16
LARGE = b"c" * 200_000  # over zenoh's batch size (65 535 bytes): sent in fragments


def listen(bus: Bus, key_expr: str) -> tuple[Subscription, list[tuple[str, bytes]]]:
    got: list[tuple[str, bytes]] = []
    sub = bus.subscribe(key_expr, lambda key, payload, _ns: got.append((key, payload)),
                        latest=False, max_queue=10_000)
    return sub, got


END = b"end"


def per_key(got: list[tuple[str, bytes]], key: str) -> list[int]:
    return [int(payload.split(b":")[0]) for k, payload in got if k == key and payload != END]


@pytest.mark.asyncio
async def test_every_sample_arrives_once_and_in_order_across_declaring_and_undeclaring(
        robot_bus: Bus, peer_bus: Bus, robot: str) -> None:
    keys = {f"ubf/{robot}/sensor/range/front": SMALL, f"ubf/{robot}/sensor/camera/front": LARGE}
    subs = [listen(robot_bus, f"ubf/{robot}/sensor/*/*"), listen(robot_bus, f"ubf/{robot}/**")]
    # Publishers that wait for room rather than drop (zenoh's default for data, under load):
    # a sample lost here would be the receiving session's doing, what this test is about.
    session = zenoh_session(peer_bus)
    pubs = {key: session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
            for key in keys}
    await eventually(lambda: all(p.matching_status.matching for p in pubs.values()),
                     what="the publishers matched")
    sent = 0

    def send(n: int) -> None:  # n samples on each key, interleaved, without waiting
        nonlocal sent
        for _ in range(n):
            sent += 1
            for key, body in keys.items():
                pubs[key].put(b"%d:" % sent + body)

    send(5)  # as key strings
    declared: list[Declaration] = [robot_bus.declare_key(key) for key in keys]
    send(40)  # the first still in flight as strings, the later ones under the session's ids
    for declaration in declared:
        declaration.undeclare()  # with samples under the ids in flight
    send(20)
    for declaration in declared:
        declaration.undeclare()  # idempotent
    for pub in pubs.values():
        pub.put(END)  # each key's last: what came before it on its key has come
    for sub, got in subs:
        await eventually(lambda got=got: sum(p == END for _, p in got) == len(keys),
                         what=f"the end of both keys on {sub.name}")
        for key in keys:
            assert per_key(got, key) == list(range(1, sent + 1)), (sub.name, key)
            assert [p for k, p in got if k == key][-1] == END, (sub.name, key)
        assert sub.stats.dropped == sub.stats.coalesced == 0
    for pub in pubs.values():
        pub.undeclare()


@pytest.mark.asyncio
async def test_a_declared_key_on_a_closed_bus_is_undeclared_quietly(
        endpoint: str, robot: str) -> None:
    from ubf_async.net.options import ConnectionOptions

    bus = await Bus.open(ConnectionOptions(robot=robot, listen=[endpoint]))
    declaration = bus.declare_key(f"ubf/{robot}/sensor/range/front")
    await bus.aclose()
    declaration.undeclare()


class Declaring(Bus):
    """An in-process bus that records the keys declared on it and which are still declared."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.declared: dict[str, bool] = {}

    def declare_key(self, key: str) -> Declaration:
        inner = super().declare_key(key)
        self.declared[key] = True
        outer = self

        class Recorded:
            def undeclare(self) -> None:
                outer.declared[key] = False
                inner.undeclare()

        return Recorded()


class Idle(Behavior):
    def act(self, state: State) -> Action | None:
        return None


@pytest.mark.asyncio
async def test_the_aggregator_declares_its_lane_sources_of_the_robot_until_it_closes() -> None:
    bus = Declaring(transport=InProcessTransport(), robot="mini")
    agg = StateAggregator(bus=bus, protected_sources=[
        "range/front", "range/left", "camera/front", "encoder/left"])
    ctl = Controller(bus=bus, aggregator=agg, root=Idle(name="idle"), mode="periodic",
                     reflex_sources=("range/",), lane=True)
    for c in (agg, ctl):
        await c.start()
    await eventually(lambda: ctl.running.is_set() and bool(bus.declared), what="the lane open")
    # the robot's own sources that tick the controller (its reflexes), not the others
    assert bus.declared == {"ubf/mini/sensor/range/front": True,
                            "ubf/mini/sensor/range/left": True}
    await ctl.aclose()
    assert all(bus.declared.values())  # kept while the aggregator listens
    await agg.aclose()
    assert not any(bus.declared.values())
    await bus.aclose()
