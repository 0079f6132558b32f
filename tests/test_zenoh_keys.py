"""A wildcard subscription on a zenoh session declares the concrete keys it hears
(``ubf_async.net.transport._KeyDeclarer``), so peers send later samples of a key under the
session's numeric id, which zenoh delivers through its cached list of subscribers instead of
matching the key string again (docs/latency.md, "The reflex at the Python floor").

Real zenoh sessions on a loopback endpoint. What must hold: nothing is lost or reordered
before, during or after a key's declaration; the declared keys are bounded; closing the
subscription undeclares them, and a new subscription still hears every key.
"""

from __future__ import annotations

from typing import Any

import pytest

from tests.conftest import eventually
from ubf_async.net import transport
from ubf_async.runtime.bus import Bus, Subscription


def declared_keys(sub: Subscription) -> set[str]:
    keys = sub._declaration._keys  # type: ignore[union-attr]
    assert keys is not None, "a wildcard subscription on zenoh declares the keys it hears"
    return keys.known


def listen(bus: Bus, key_expr: str) -> tuple[Subscription, list[tuple[str, bytes]]]:
    got: list[tuple[str, bytes]] = []
    sub = bus.subscribe(key_expr, lambda key, payload, _ns: got.append((key, payload)),
                        latest=False)
    return sub, got


async def send(peer_bus: Bus, keys: list[str], first: int, last: int) -> None:
    """Samples ``first..last`` on each of ``keys``, interleaved."""
    pubs = [peer_bus.raw_publisher(k) for k in keys]
    for pub in pubs:
        await pub.wait_for_subscribers()
    for n in range(first, last + 1):
        for pub in pubs:
            pub.put(str(n).encode())
    for pub in pubs:
        pub.close()


def per_key(got: list[tuple[str, bytes]], key: str) -> list[int]:
    return [int(payload) for k, payload in got if k == key]


@pytest.mark.asyncio
async def test_every_sample_arrives_in_order_across_the_declaration(
    robot_bus: Bus, peer_bus: Bus, robot: str
) -> None:
    sub, got = listen(robot_bus, f"ubf/{robot}/sensor/*/*")
    keys = [f"ubf/{robot}/sensor/range/front", f"ubf/{robot}/sensor/range/left"]
    await send(peer_bus, keys, 1, 1)  # heard, then declared
    await eventually(lambda: declared_keys(sub) == set(keys), what="both keys declared")
    await send(peer_bus, keys, 2, 40)  # sent under the declared ids
    await eventually(lambda: len(got) == 80, what="80 samples")
    for key in keys:
        assert per_key(got, key) == list(range(1, 41))
    sub.close()


@pytest.mark.asyncio
async def test_the_declared_keys_are_bounded_and_the_others_still_heard(
    robot_bus: Bus, peer_bus: Bus, robot: str, monkeypatch: Any
) -> None:
    monkeypatch.setattr(transport, "MAX_DECLARED_KEYS", 2)
    sub, got = listen(robot_bus, f"ubf/{robot}/sensor/*/*")
    keys = [f"ubf/{robot}/sensor/range/{name}" for name in ("a", "b", "c", "d")]
    for key in keys:  # one at a time: which keys come first decides which are declared
        await send(peer_bus, [key], 1, 1)
        await eventually(lambda key=key: key in {k for k, _ in got}, what=key)
    assert declared_keys(sub) == set(keys[:2])
    await send(peer_bus, keys, 2, 10)
    await eventually(lambda: len(got) == 40, what="40 samples")
    for key in keys:
        assert per_key(got, key) == list(range(1, 11))
    assert declared_keys(sub) == set(keys[:2])
    sub.close()


@pytest.mark.asyncio
async def test_closing_undeclares_them_and_a_new_subscription_hears_every_key(
    robot_bus: Bus, peer_bus: Bus, robot: str
) -> None:
    key = f"ubf/{robot}/sensor/range/front"
    sub, got = listen(robot_bus, f"ubf/{robot}/sensor/*/*")
    await send(peer_bus, [key], 1, 1)
    await eventually(lambda: declared_keys(sub) == {key} and len(got) == 1,
                     what="the key declared and its sample handled")
    declarer = sub._declaration._keys  # type: ignore[union-attr]
    watch = peer_bus.raw_publisher(key)
    sub.close()
    assert declarer._declared == [] and declarer.full
    # The peer must know the old subscription gone before it can tell the new one is there.
    await watch.wait_for_subscribers(present=False)
    again, got_again = listen(robot_bus, f"ubf/{robot}/sensor/*/*")
    watch.close()
    await send(peer_bus, [key], 2, 20)
    await eventually(lambda: len(got_again) == 19, what="19 samples after the undeclaration")
    assert per_key(got_again, key) == list(range(2, 21))
    assert len(got) == 1
    again.close()


@pytest.mark.asyncio
async def test_an_exact_subscription_declares_nothing_more(robot_bus: Bus, robot: str) -> None:
    sub, _ = listen(robot_bus, f"ubf/{robot}/sensor/range/front")
    assert sub._declaration._keys is None  # type: ignore[union-attr]
    sub.close()
