"""The lending event loop (ubf_async.runtime.lending): a transport thread runs a short handler at
once while the loop waits in select(), never beside loop code, and whatever it schedules is
run by the loop thread; direct subscriptions and the reflex path use it on real zenoh."""

from __future__ import annotations

import asyncio
import threading
import time
from typing import Any

import msgpack
import pytest

from tests.conftest import eventually
from ubf_async import Action, FunctionBehavior
from ubf_async.cli.run import loop_factory
from ubf_async.runtime.aggregator import StateAggregator
from ubf_async.runtime.bus import DIRECT_BURST, DIRECT_RATE_HZ, Bus
from ubf_async.runtime.controller import Controller
from ubf_async.runtime.lending import (
    LendingEventLoop,
    _take,
    idle_waiter,
    new_event_loop,
    new_idle_event_loop,
    run_if_idle,
)
from ubf_async.wire.protocol import decode
from ubf_async.wire.topics import DRIVE


def lend_when_idle(run: Any, fn: Any, *args: Any) -> bool:
    """Borrow the loop as soon as it waits in select() (the test awaits meanwhile, so it
    soon does); ``False`` if it never did within 10 s."""
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        if run(fn, *args):
            return True
    return False


# ---------------------------------------------------------------------------------------------
# The loop


@pytest.mark.asyncio
async def test_these_tests_run_on_the_lending_loop_that_ubf_loop_lending_chooses(
        monkeypatch: pytest.MonkeyPatch) -> None:
    loop = asyncio.get_running_loop()
    assert isinstance(loop, LendingEventLoop) and loop.lends
    monkeypatch.setenv("UBF_LOOP", "lending")
    assert loop_factory() is new_event_loop


def test_a_loop_that_does_not_lend_tells_when_it_is_idle_and_lends_nothing() -> None:
    """The entry points' default (:func:`new_idle_event_loop`): the lockstep's ``idle()``,
    no borrowing."""
    loop = new_idle_event_loop()
    try:
        assert not loop.lends
        assert run_if_idle(loop) is None  # the bus takes the usual road
        assert not isinstance(loop, LendingEventLoop)
        assert idle_waiter(loop) is not None

        async def idle_then_done() -> str:
            done = asyncio.Event()
            asyncio.get_running_loop().call_soon(done.set)
            await loop.idle()  # returns only once the callback has run
            return "idle after set" if done.is_set() else "idle too early"

        assert loop.run_until_complete(idle_then_done()) == "idle after set"
    finally:
        loop.close()


@pytest.mark.asyncio
async def test_an_idle_loop_runs_the_callback_on_the_calling_thread_as_if_it_were_the_loop(
) -> None:
    loop = asyncio.get_running_loop()
    run = run_if_idle(loop)
    assert run is not None
    seen: dict[str, Any] = {}

    def callback(value: int) -> None:
        seen["thread"] = threading.get_ident()
        seen["running loop"] = asyncio.get_running_loop()
        seen["value"] = value

    before = loop.lent_runs  # type: ignore[attr-defined]
    # The loop thread awaits the thread, so it waits in select() meanwhile.
    assert await asyncio.to_thread(lend_when_idle, run, callback, 7) is True
    assert seen["value"] == 7
    assert seen["thread"] != threading.get_ident()
    assert seen["running loop"] is loop
    assert loop.lent_runs == before + 1  # type: ignore[attr-defined]


@pytest.mark.asyncio
async def test_on_the_loop_thread_or_while_the_loop_is_busy_nothing_is_lent() -> None:
    loop = asyncio.get_running_loop()
    run = run_if_idle(loop)
    assert run is not None
    ran: list[str] = []
    # On its own thread the loop is busy running the caller.
    assert run(ran.append, "own thread") is False
    # Busy: the loop thread runs a callback (this test's code) while another thread asks.
    asked = threading.Event()
    answer: list[bool] = []

    def ask() -> None:
        answer.append(run(ran.append, "while busy"))
        asked.set()

    threading.Thread(target=ask, daemon=True).start()
    assert asked.wait(10)  # blocks the loop thread on purpose: it is busy throughout
    assert answer == [False]
    assert ran == []


@pytest.mark.asyncio
async def test_what_a_borrower_schedules_wakes_the_loop_thread() -> None:
    """The loop sleeps in select() with a long timeout; a future resolved and a timer set by
    the borrower still run at once, on the loop thread."""
    loop = asyncio.get_running_loop()
    run = run_if_idle(loop)
    assert run is not None
    future: asyncio.Future[str] = loop.create_future()
    timer_ran = asyncio.Event()
    threads: list[int] = []

    def borrower() -> None:
        future.set_result("resolved")
        loop.call_later(0.01, lambda: (threads.append(threading.get_ident()), timer_ran.set()))

    waiter = asyncio.ensure_future(asyncio.wait_for(future, 30))
    await asyncio.sleep(0)  # the waiter is waiting
    assert await asyncio.to_thread(lend_when_idle, run, borrower) is True
    assert await waiter == "resolved"
    await asyncio.wait_for(timer_ran.wait(), 30)
    assert threads == [threading.get_ident()]  # run by the loop thread


@pytest.mark.asyncio
async def test_an_exception_reaches_the_borrower_and_the_loop_is_given_back() -> None:
    loop = asyncio.get_running_loop()
    run = run_if_idle(loop)
    assert run is not None

    def fails() -> None:
        raise ValueError("handler bug")

    with pytest.raises(ValueError, match="handler bug"):
        await asyncio.to_thread(lend_when_idle, run, fails)
    # The loop still works and can be lent again.
    await asyncio.sleep(0)
    assert await asyncio.to_thread(lend_when_idle, run, lambda: None) is True


def test_a_closed_loop_and_a_loop_in_debug_mode_lend_nothing() -> None:
    loop = new_event_loop()
    loop.set_debug(True)
    ran: list[int] = []

    async def ask() -> bool:
        return bool(await asyncio.to_thread(loop.run_if_idle, ran.append, 1))

    assert loop.run_until_complete(ask()) is False
    loop.close()
    assert loop.run_if_idle(ran.append, 2) is False
    assert ran == []
    plain = asyncio.SelectorEventLoop()  # any other loop lends nothing
    assert run_if_idle(plain) is None
    plain.close()


LOOP_TURNS = 300


@pytest.mark.asyncio
async def test_borrowers_never_run_beside_loop_code() -> None:
    """Four threads borrow the loop as often as they can while the loop thread runs a
    stream of callbacks and timers; a shared flag catches any overlap, and the loop thread
    is not starved (it goes first whenever its select() returns): its 300 turns all come,
    however busy the machine (a count, not a rate in wall time)."""
    loop = asyncio.get_running_loop()
    run = run_if_idle(loop)
    assert run is not None
    inside = [0]
    overlaps = [0]
    counts = {"loop": 0, "lent": 0}
    stop = threading.Event()

    def critical(who: str) -> None:
        inside[0] += 1
        if inside[0] != 1:
            overlaps[0] += 1
        for _ in range(50):  # long enough for the other side to try its luck
            pass
        counts[who] += 1
        inside[0] -= 1

    def borrower() -> None:  # a thread bringing samples as fast as it can
        while not stop.is_set():
            run(critical, "lent")
            time.sleep(0.0001)  # pacing, so the test does not fight over the GIL alone

    threads = [threading.Thread(target=borrower, daemon=True) for _ in range(4)]
    for t in threads:
        t.start()
    try:
        for _ in range(LOOP_TURNS):
            critical("loop")
            await asyncio.sleep(0.0005)  # the loop waits in select(): borrowers may come
        await eventually(lambda: counts["lent"] > 0, timeout_s=30,
                         what="a borrower to get in (the loop waiting in select)")
    finally:
        stop.set()
        for t in threads:
            t.join(10)
    assert overlaps[0] == 0
    assert counts["loop"] == LOOP_TURNS and counts["lent"] > 0, counts  # both sides got in


def test_taking_the_lock_survives_an_interrupt_while_waiting() -> None:
    """A signal handler that raises while the loop thread waits for a borrower (Ctrl-C's
    KeyboardInterrupt) must not leave the loop without its lock."""

    class InterruptedOnce:
        def __init__(self) -> None:
            self.lock = threading.Lock()
            self.calls = 0

        def acquire(self) -> bool:
            self.calls += 1
            if self.calls == 1:
                raise KeyboardInterrupt  # what Python's SIGINT handler raises mid-wait
            return self.lock.acquire()

    lock = InterruptedOnce()
    with pytest.raises(KeyboardInterrupt):
        _take(lock)  # type: ignore[arg-type]
    assert lock.calls == 2 and lock.lock.locked()  # re-raised only once the lock is held


# ---------------------------------------------------------------------------------------------
# On real zenoh: direct subscriptions and the reflex path


@pytest.mark.asyncio
async def test_a_direct_subscription_handles_a_remote_sample_on_zenohs_thread(
        robot_bus: Bus, peer_bus: Bus) -> None:
    key = f"ubf/{robot_bus.robot}/test/direct"
    direct: list[tuple[int, int]] = []
    usual: list[tuple[int, int]] = []
    loop_thread = threading.get_ident()
    sub_direct = robot_bus.subscribe(key, lambda k, p, t: direct.append(
        (threading.get_ident(), int(p))), direct=True)
    sub_usual = robot_bus.subscribe(key, lambda k, p, t: usual.append(
        (threading.get_ident(), int(p))))
    out = peer_bus.raw_publisher(key)
    await eventually(lambda: out._out.has_remote_subscribers(), what="the subscribers")
    for i in range(20):
        out.put(str(i).encode())
        await eventually(lambda i=i: len(direct) > i and len(usual) > i, what=f"sample {i}")
    assert [v for _, v in direct] == list(range(20)) == [v for _, v in usual]
    assert all(thread == loop_thread for thread, _ in usual)
    # Whenever the loop was idle the direct handler ran on zenoh's thread at once.
    assert sub_direct.stats.direct > 0
    assert any(thread != loop_thread for thread, _ in direct)
    assert sub_usual.stats.direct == 0
    assert sub_direct.stats.handler_errors == 0


@pytest.mark.asyncio
@pytest.mark.parametrize("lane", [False, True], ids=["lent", "lane"])
async def test_a_reflex_is_answered_on_the_thread_that_brought_its_sample(
        robot_bus: Bus, peer_bus: Bus, lane: bool) -> None:
    """A range sample from another session ticks the controller inside ingest, on zenoh's
    thread: lent the idle loop, or on the reflex lane (which needs no lending: it takes every
    sample of its key); the drive command based on it reaches the sender."""
    agg = StateAggregator(bus=robot_bus)
    behavior = FunctionBehavior(
        lambda s: None if s.range("front") is None else Action(speed=-50.0, turn=0.0),
        name="avoid")
    ctl = Controller(bus=robot_bus, aggregator=agg, root=behavior, mode="event",
                     trigger="range/front", rate_hz=50.0, lane=lane)
    tick_threads: list[int] = []
    ctl.on_tick(lambda state, trace, command: tick_threads.append(threading.get_ident()))
    for c in (agg, ctl):
        await c.start()
    for c in (agg, ctl):
        await asyncio.wait_for(c.running.wait(), 5)
    replies: list[dict[str, Any]] = []
    drive_sub = peer_bus.subscribe(DRIVE.key(peer_bus.keys), lambda k, p, t: replies.append(
        msgpack.unpackb(p)), latest=False)
    key = f"ubf/{robot_bus.robot}/sensor/range/front"
    out = peer_bus.raw_publisher(key)
    try:
        await eventually(lambda: out._out.has_remote_subscribers(), what="the aggregator")
        for seq in range(1, 31):
            out.put(msgpack.packb({"schema": "range", "v": 1, "seq": seq,
                                   "stamp_ns": robot_bus.clock.now_ns(),
                                   "data": {"range_mm": 120, "status": "ok"}}))
            await eventually(lambda seq=seq: any(
                (r["data"].get("based_on") or {}).get("seq") == seq for r in replies),
                what=f"the command based on sample {seq}")
        answered = [decode(msgpack.packb(r), topic=DRIVE).data for r in replies]
        assert all(d.speed == -50.0 for d in answered if d.based_on is not None)
        assert ctl.stats.triggered == 30
        stats = agg.subscription.stats if agg.subscription is not None else None
        assert stats is not None
        if lane:
            assert (stats.lane, stats.direct) == (30, 0)
        else:
            assert stats.direct > 0 and stats.lane == 0
        loop_thread = threading.get_ident()
        assert any(t != loop_thread for t in tick_threads)
    finally:
        drive_sub.close()
        await ctl.aclose()
        await agg.aclose()


@pytest.mark.asyncio
async def test_a_flood_takes_the_usual_road_beyond_the_direct_budget(
        robot_bus: Bus, peer_bus: Bus) -> None:
    """Samples handled on zenoh's thread are capped at DIRECT_RATE_HZ (after a burst); the
    rest coalesce on the usual road, and every handler call still comes in order."""
    key = f"ubf/{robot_bus.robot}/test/flood"
    seen: list[int] = []
    sub = robot_bus.subscribe(key, lambda k, p, t: seen.append(int(p)), direct=True)
    out = peer_bus.raw_publisher(key)
    await eventually(lambda: out._out.has_remote_subscribers(), what="the subscriber")
    count = 20_000

    def flood() -> float:
        t0 = time.monotonic()
        for i in range(count):
            out.put(str(i).encode())
        return time.monotonic() - t0

    started = time.monotonic()
    await asyncio.to_thread(flood)
    await eventually(lambda: bool(seen) and seen[-1] == count - 1, timeout_s=30,
                     what="the flood's last sample")
    elapsed_s = time.monotonic() - started
    stats = sub.stats
    assert stats.direct <= DIRECT_BURST + DIRECT_RATE_HZ * elapsed_s + 1, (stats, elapsed_s)
    assert stats.coalesced > 0  # beyond the budget the bridge kept the newest per key
    assert stats.delivered == len(seen) and seen == sorted(seen)  # in order, none twice
