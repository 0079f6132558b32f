"""Per-key bookkeeping stays bounded whatever keys arrive (issue 13, "Bounded everything")."""

from __future__ import annotations

import asyncio
import itertools

import pytest

from ubf_async.errors import ProtocolError
from ubf_async.runtime.bus import DRAIN_BATCH, Subscription, TopicScreen
from ubf_async.runtime.component import MAX_WATCHED_COMPONENTS, HealthMonitor
from ubf_async.wire.protocol import MAX_COUNTED_KEYS, decode_or_count
from ubf_async.wire.topics import DRIVE


def test_malformed_counts_keep_at_most_max_counted_keys() -> None:
    counter: dict[str, int] = {}
    for i in range(MAX_COUNTED_KEYS + 500):
        assert decode_or_count(b"\xc1junk", counter, f"ubf/r/sensor/junk/{i}") is None
    assert len(counter) == MAX_COUNTED_KEYS
    assert f"ubf/r/sensor/junk/{MAX_COUNTED_KEYS + 499}" in counter  # the newest are kept
    assert "ubf/r/sensor/junk/0" not in counter


@pytest.mark.asyncio
async def test_a_flood_of_distinct_keys_is_capped_and_drained_in_slices() -> None:
    loop = asyncio.get_running_loop()
    seen: list[str] = []
    passes: list[int] = []  # how many samples each loop pass delivered

    def handler(key: str, payload: bytes, received_ns: int) -> None:
        seen.append(key)

    sub = Subscription(loop, handler, latest=True, max_queue=1000)
    other_task_ran = asyncio.Event()

    async def other_task() -> None:  # must get a turn while the flood is drained
        while len(seen) < 1000:
            passes.append(len(seen))
            await asyncio.sleep(0)
        other_task_ran.set()

    for i in range(3000):  # from a zenoh thread these would arrive while the loop is busy
        sub.push(f"k/{i}", b"x", on_loop=True)
    assert sub.stats.dropped == 2000 and sub.stats.received == 3000
    task = asyncio.create_task(other_task())
    await asyncio.wait_for(other_task_ran.wait(), 5)
    await task
    assert seen == [f"k/{i}" for i in range(1000)]
    # Several passes of the loop, none delivering more than one slice.
    steps = [b - a for a, b in itertools.pairwise(passes) if b > a]
    assert steps and max(steps) <= DRAIN_BATCH
    sub.close()


@pytest.mark.asyncio
async def test_garbage_over_distinct_keys_keeps_at_most_max_queue_refusal_slots() -> None:
    accepted: list[str] = []
    malformed: dict[str, int] = {}
    all_reported = asyncio.Event()

    def on_error(key: str, error: ProtocolError) -> None:
        if len(malformed) == 100:
            all_reported.set()

    screen = TopicScreen(DRIVE, lambda key, message, t: accepted.append(key), malformed,
                         on_error=on_error)
    sub = Subscription(asyncio.get_running_loop(), None, latest=True, max_queue=100,
                       screen=screen)
    for i in range(1000):
        sub.push(f"junk/{i}", b"\xc1", on_loop=True)
        sub.push("junk/0", b"\xc1", on_loop=True)  # one key's refusals share one slot
    await asyncio.wait_for(all_reported.wait(), 5)
    assert not sub.pending
    assert len(malformed) == 100 and malformed["junk/0"] == 1001
    assert sub.stats.refused == 1100 and sub.stats.dropped == 900
    assert accepted == []
    sub.close()


class _Keys:
    def component_of_alive(self, key: str) -> str:
        return key.rsplit("/", 1)[-1]


class _Bus:
    keys = _Keys()


def test_health_monitor_forgets_departed_components_first_when_full() -> None:
    monitor = HealthMonitor(_Bus())  # type: ignore[arg-type]
    monitor._on_liveliness("ubf/r/alive/real", True)
    for i in range(MAX_WATCHED_COMPONENTS + 100):
        monitor._on_liveliness(f"ubf/r/alive/junk{i}", True)
        monitor._on_liveliness(f"ubf/r/alive/junk{i}", False)
    assert len(monitor.components) == MAX_WATCHED_COMPONENTS
    assert monitor.components["real"].alive  # a live component is never the one forgotten
