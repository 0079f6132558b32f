"""The reflex lane (issue 40): a sample that ticks the controller is stored, and its tick run,
on the thread that brought it, under the aggregator's lock.

One zenoh session (the drive commands go out through it; a lane's put must be thread-safe,
which the in-process transport is not, by design) and a plain thread calling the aggregator
subscription's ``push``, standing in for zenoh's callback thread: every sample, and its
moment, is the test's. The lane across two sessions is covered by tests/test_lending.py's
reflex test. No test asserts a time: each asserts which thread ran, counts and order.
"""

from __future__ import annotations

import asyncio
import logging
import threading
import time
from collections.abc import AsyncIterator, Callable
from contextlib import asynccontextmanager
from typing import Any

import pytest

from tests.conftest import eventually
from ubf_async import Action, Behavior, State
from ubf_async.clocks.clock import Clock, SimClock, WallClock
from ubf_async.net.options import ConnectionOptions
from ubf_async.runtime.aggregator import StateAggregator
from ubf_async.runtime.bus import Bus, Subscription
from ubf_async.runtime.controller import Controller
from ubf_async.wire.protocol import encode
from ubf_async.wire.topics import RANGE

KEY_SOURCE = "range/front"


class Exclusive(Behavior):
    """Backs off on a near reading; records which threads ran it and whether two ever
    overlapped inside ``act``."""

    def __init__(self) -> None:
        super().__init__(name="exclusive")
        self.inside = False
        self.overlaps = 0
        self.threads: set[int] = set()

    def act(self, state: State) -> Action | None:
        if self.inside:
            self.overlaps += 1
        self.inside = True
        self.threads.add(threading.get_ident())
        time.sleep(0)  # gives the GIL away here, where another tick would overlap this one
        self.inside = False
        return None if state.get(KEY_SOURCE) is None else Action(speed=-50.0, turn=0.0)


def sample(clock: Clock, seq: int, mm: int = 120) -> bytes:
    return encode(RANGE, {"range_mm": mm, "status": "ok"}, stamp_ns=clock.now_ns(), seq=seq)


async def from_thread(push: Callable[[], None]) -> None:
    """Run ``push`` on another thread, as the transport's callback thread would."""
    thread = threading.Thread(target=push)
    thread.start()
    await asyncio.to_thread(thread.join)


@asynccontextmanager
async def robot(clock: Clock, endpoint: str, **controller: Any
                ) -> AsyncIterator[tuple[StateAggregator, Controller, Subscription, str]]:
    bus = await Bus.open(ConnectionOptions(robot="lane", listen=[endpoint]), clock=clock)
    agg = StateAggregator(bus=bus)
    options: dict[str, Any] = {"mode": "event", "trigger": KEY_SOURCE, "rate_hz": 50.0,
                               **controller}
    ctl = Controller(bus=bus, aggregator=agg, root=controller.pop("root", Exclusive()),
                     **{k: v for k, v in options.items() if k != "root"})
    try:
        for c in (agg, ctl):
            await c.start()
        for c in (agg, ctl):
            await asyncio.wait_for(c.running.wait(), 5)
        assert agg.subscription is not None
        yield agg, ctl, agg.subscription, bus.keys.sensor("range", "front")
    finally:
        await ctl.aclose()
        await agg.aclose()
        await bus.aclose()


def ticks_until(ctl: Controller, n: int) -> asyncio.Event:
    """An event set (on the loop) once ``ctl`` has run ``n`` triggered ticks."""
    done = asyncio.Event()

    def hook(state: State, trace: Any, command: Any) -> None:
        if ctl.stats.triggered >= n:
            ctl.bus.call_on_loop(done.set)

    ctl.on_tick(hook)
    return done


@pytest.mark.asyncio
async def test_on_wall_clock_a_trigger_sample_ticks_on_its_own_thread_and_hands_the_loop_its_part(
        endpoint: str) -> None:
    clock = WallClock()
    async with robot(clock, endpoint) as (agg, ctl, sub, key):
        behavior = ctl.root
        assert isinstance(behavior, Exclusive)
        first = ticks_until(ctl, 1)
        await from_thread(lambda: sub.push(key, sample(clock, 1)))  # the source is new
        await asyncio.wait_for(first.wait(), 5)
        # Loop-affine parts are handed over: an update waiter and the ticked event.
        waiter = asyncio.create_task(agg.wait_for_update(KEY_SOURCE, after_version=1))
        ctl.ticked.clear()
        await from_thread(lambda: sub.push(key, sample(clock, 2)))
        entry = await asyncio.wait_for(waiter, 5)
        await asyncio.wait_for(ctl.ticked.wait(), 5)
        assert entry.message.seq == 2
        assert (sub.stats.lane, sub.stats.received, sub.stats.delivered) == (2, 2, 2)
        assert ctl.stats.triggered == 2
        assert threading.get_ident() not in behavior.threads  # never the loop's thread
        # Closed with the controller's run: later samples take the loop's road.
        await ctl.aclose()
        await from_thread(lambda: sub.push(key, sample(clock, 3)))
        await eventually_delivered(sub, 3)
        assert sub.stats.lane == 2 and agg.entries[KEY_SOURCE].message.seq == 3


async def eventually_delivered(sub: Subscription, n: int) -> None:
    """Wait for the loop's drain to deliver ``n`` samples."""
    await eventually(lambda: sub.stats.delivered >= n, what=f"{n} samples delivered")


@pytest.mark.asyncio
async def test_on_simulated_time_every_sample_goes_through_the_loop(
        endpoint: str) -> None:
    clock = SimClock(start_ns=10**9)
    async with robot(clock, endpoint) as (_agg, ctl, sub, key):
        behavior = ctl.root
        assert isinstance(behavior, Exclusive)
        done = ticks_until(ctl, 3)
        for seq in (1, 2, 3):
            await from_thread(lambda seq=seq: sub.push(key, sample(clock, seq)))
            await eventually_delivered(sub, seq)
        await asyncio.wait_for(done.wait(), 5)
        assert sub.stats.lane == 0 and sub.stats.delivered == 3
        assert behavior.threads == {threading.get_ident()}


@pytest.mark.asyncio
async def test_no_sample_overtakes_an_elder_of_its_key_waiting_for_the_loop(
        endpoint: str) -> None:
    """The loop holds the lock: the lane waits its bound, then hands the sample to the loop.
    The next sample finds the lock free but its elder still queued: it joins it there
    (replacing it, as the loop's road does), instead of being stored first and getting its
    elder refused as out of order."""
    clock = WallClock()
    async with robot(clock, endpoint) as (agg, ctl, sub, key):
        await from_thread(lambda: sub.push(key, sample(clock, 1)))
        assert sub.stats.lane == 1
        second = ticks_until(ctl, 2)
        with agg.lock:  # the loop busy with its own work (a tick, a drain)
            thread = threading.Thread(target=sub.push, args=(key, sample(clock, 2)))
            thread.start()
            thread.join()  # (the loop thread blocks here: the drain cannot run yet)
        assert (sub.stats.lane_busy, sub.pending) == (1, True)
        thread = threading.Thread(target=sub.push, args=(key, sample(clock, 3)))
        thread.start()
        thread.join()
        assert (sub.stats.lane_deferred, sub.stats.coalesced, sub.stats.lane) == (1, 1, 1)
        await asyncio.wait_for(second.wait(), 5)
        assert agg.entries[KEY_SOURCE].message.seq == 3
        assert agg.refused == {}  # nothing out of order
        assert ctl.last_trace is not None and ctl.stats.triggered == 2


@pytest.mark.asyncio
async def test_a_burst_on_the_lane_loses_nothing_and_keeps_its_order(
        endpoint: str) -> None:
    clock = WallClock()
    async with robot(clock, endpoint) as (agg, ctl, sub, key):
        based_on: list[int] = []
        ctl.on_tick(lambda state, trace, command: based_on.append(command.based_on.seq))
        n = 300
        done = ticks_until(ctl, n)
        payloads = [sample(clock, seq) for seq in range(1, n + 1)]
        await from_thread(lambda: [sub.push(key, p) for p in payloads])
        await asyncio.wait_for(done.wait(), 5)
        assert based_on == list(range(1, n + 1))
        assert sub.stats.lane == n and sub.stats.coalesced == sub.stats.dropped == 0
        assert agg.refused == {} and ctl.stats.errors == 0


@pytest.mark.asyncio
async def test_a_malformed_sample_on_the_lane_key_is_counted_and_logged_and_the_lane_goes_on(
        endpoint: str, caplog: pytest.LogCaptureFixture) -> None:
    clock = WallClock()
    caplog.set_level(logging.WARNING)
    async with robot(clock, endpoint) as (agg, ctl, sub, key):
        def burst() -> None:
            sub.push(key, sample(clock, 1))
            sub.push(key, b"\xc1 not msgpack")
            sub.push(key, sample(clock, 2)[:-1])  # cut short
            sub.push(key, sample(clock, 3))

        done = ticks_until(ctl, 2)
        await from_thread(burst)
        await asyncio.wait_for(done.wait(), 5)
        await eventually_delivered(sub, 2)
        # The refusals are reported by the loop's drain.
        await eventually(lambda: agg.malformed.get(key) == 2, what="both refusals counted")
        assert agg.malformed == {key: 2}
        assert sub.stats.refused == 2 and sub.stats.lane == 2
        assert agg.entries[KEY_SOURCE].message.seq == 3
        assert any("malformed" in r.getMessage() and key in r.getMessage()
                   for r in caplog.records)


@pytest.mark.asyncio
async def test_the_lane_and_the_loop_never_tick_the_tree_at_once(
        endpoint: str) -> None:
    """Periodic 500 Hz on the loop plus reflexes on the lane: both threads run the tree, never
    together (the behaviour gives the GIL away inside ``act``, where an overlap would show).

    Samples come until the lane has ticked ``n`` times. A sample finding the loop's tick
    holding the lock past :data:`~ubf_async.runtime.bus.LANE_WAIT_S` (a busy machine) is
    handed to the loop, and those after it join it there, the newest replacing the others
    (the loop's road): so not every sample ticks, but each either ticks, in order, or is
    replaced by a newer one."""
    clock = WallClock()
    async with robot(clock, endpoint, mode="periodic", trigger=None, rate_hz=500.0,
                     reflex_sources=("range/",), reflex_rate_hz=10_000.0,
                     reflex_burst=1000) as (agg, ctl, sub, key):
        behavior = ctl.root
        assert isinstance(behavior, Exclusive)
        n = 400
        reflexes: list[int] = []  # the seq each reflex tick was based on, on either thread

        def hook(state: State, trace: Any, command: Any) -> None:
            if command.ticked_by == "reflex":
                reflexes.append(command.based_on.seq)

        ctl.on_tick(hook)
        pushed = 0
        stop = threading.Event()  # (only should the lane never take one: no thread left behind)

        def push() -> None:
            nonlocal pushed
            while sub.stats.lane < n and not stop.is_set():
                pushed += 1  # stamped as it goes, as a sensor's sample would be
                sub.push(key, sample(clock, pushed))

        try:
            await asyncio.wait_for(from_thread(push), 5)
        finally:
            stop.set()
        # The last sample took the lane (and ticked there): nothing waits for the loop.
        stats = sub.stats
        assert stats.lane == n and not sub.pending
        assert stats.received == stats.delivered + stats.coalesced == pushed
        assert stats.dropped == stats.refused == 0
        assert agg.refused == {} and ctl.stats.reflex_limited == 0 and ctl.stats.errors == 0
        assert ctl.stats.triggered == stats.delivered == len(reflexes)
        assert reflexes == sorted(set(reflexes)) and reflexes[-1] == pushed
        periodic = ctl.stats.periodic
        while ctl.stats.periodic < periodic + 3:  # and the loop's own ticks go on
            ctl.ticked.clear()
            await asyncio.wait_for(ctl.ticked.wait(), 5)
        assert behavior.overlaps == 0
        assert threading.get_ident() in behavior.threads and len(behavior.threads) == 2


@pytest.mark.asyncio
async def test_a_trigger_sample_published_from_a_tick_on_the_lane_waits_for_the_loop(
        endpoint: str) -> None:
    """A tick hook that publishes a sample of the trigger source on the same bus (from the
    lane's thread): not delivered inside the tick that published it — the lock is
    re-entrant, so it would tick again from within, and again — but queued for the loop,
    which stores it (and ticks on it) after."""
    clock = WallClock()
    async with robot(clock, endpoint) as (agg, ctl, sub, key):
        echo = agg.bus.publisher(RANGE, "front")
        depth = 0
        deepest = 0
        published: list[int] = []

        def hook(state: State, trace: Any, command: Any) -> None:
            nonlocal depth, deepest
            depth += 1
            deepest = max(deepest, depth)
            if not published:  # once: the first lane tick publishes one more sample
                published.append(echo.publish({"range_mm": 99, "status": "ok"})[0])
            depth -= 1

        ctl.on_tick(hook)
        done = ticks_until(ctl, 2)
        await from_thread(lambda: sub.push(key, sample(clock, 1)))
        await asyncio.wait_for(done.wait(), 5)
        assert deepest == 1, "a tick ran inside another"
        assert sub.stats.lane == 1 and sub.stats.delivered == 2
        assert agg.entries[KEY_SOURCE].message.data.range_mm == 99
        echo.close()
