"""Time across hosts (issue 16, item 3): a wall-time robot publishes its clock on
ubf/<robot>/time; a process whose host clock is elsewhere learns the offset and stamps on the
robot's clock, so the robot computes its samples' ages right."""

from __future__ import annotations

import asyncio
import itertools
import sys
import time
from collections.abc import Callable

import pytest

from tests.conftest import eventually, read_until
from ubf_async.clocks import follow
from ubf_async.clocks.clock import WallClock
from ubf_async.clocks.hostclock import OffsetEstimator, RobotTimeClock
from ubf_async.net.inprocess import InProcessTransport
from ubf_async.net.options import ConnectionOptions
from ubf_async.runtime.aggregator import StateAggregator
from ubf_async.runtime.bus import Bus
from ubf_async.runtime.timekeepers import RobotTimeBeacon
from ubf_async.wire.protocol import decode
from ubf_async.wire.topics import RANGE, ROBOT_TIME

S = 10**9
MS = 10**6
HOUR_NS = 3600 * S


def test_the_offset_is_the_largest_recent_sample_and_restarts_on_a_jump() -> None:
    estimator = OffsetEstimator(window=4)
    true_offset = 1234 * S
    for latency in (3 * MS, 1 * MS, 2 * MS):  # robot stamp t, arrival t + latency − offset
        estimator.offer(robot_stamp_ns=100 * S, local_arrival_ns=100 * S + latency - true_offset)
    assert estimator.offset_ns == true_offset - 1 * MS  # early by the smallest latency
    assert estimator.spread_ns == 2 * MS
    for _ in range(4):  # the 1 ms sample slides out of the window
        estimator.offer(robot_stamp_ns=0, local_arrival_ns=2 * MS - true_offset)
    assert estimator.offset_ns == true_offset - 2 * MS
    estimator.offer(robot_stamp_ns=0, local_arrival_ns=-true_offset - 5 * S)  # a restart
    assert estimator.restarts == 1 and estimator.offset_ns == true_offset + 5 * S
    with pytest.raises(RuntimeError):
        _ = OffsetEstimator().offset_ns


def shifted(offset_ns: int) -> Callable[[], int]:
    """Another host's monotonic clock: this one's, started ``offset_ns`` earlier."""
    return lambda: time.monotonic_ns() + offset_ns


class OtherHostClock(WallClock):
    """What a process on another host stamps with when it follows nothing."""

    def __init__(self, offset_ns: int) -> None:
        self.now_ns = shifted(offset_ns)  # type: ignore[method-assign]


@pytest.mark.asyncio
async def test_a_pause_between_the_followers_clock_reads_makes_it_early_never_ahead() -> None:
    """The follower carries each sample's arrival (stamped on CLOCK_MONOTONIC) to its own
    clock with two reads; a busy machine may pause it between them. The pause must make the
    estimate early: a robot-time stamp ahead of the robot is a sample from its future."""
    host_offset_ns = HOUR_NS

    def paused_after_reading() -> int:
        now = time.monotonic_ns() + host_offset_ns
        time.sleep(0.005)  # the process preempted just after this read
        return now

    net = InProcessTransport()
    robot_bus = Bus(transport=net, robot="r1")  # on CLOCK_MONOTONIC: the robot's time
    follower_bus = Bus(transport=net, robot="r1")
    followed = RobotTimeClock(local_ns=paused_after_reading)
    try:
        subscription = followed.follow(follower_bus)
        beacon = robot_bus.publisher(ROBOT_TIME)
        for _ in range(3):
            beacon.publish({"host": "robot"})
            await net.settle()
        assert followed.ready.is_set()
        # robot time − local time is −host_offset_ns; learned, it may only be smaller.
        assert followed.estimator.offset_ns <= -host_offset_ns
        subscription.close()
    finally:
        await follower_bus.aclose()
        await robot_bus.aclose()


@pytest.mark.asyncio
@pytest.mark.parametrize("other_host", ["up an hour longer", "booted 30 s ago"])
async def test_a_sender_on_another_clock_stamps_on_the_robots(
    robot_bus: Bus, endpoint: str, robot: str, other_host: str
) -> None:
    """Two real zenoh sessions whose clocks are deliberately apart: the one that follows
    ubf/<robot>/time gets its samples' ages right; the one that stamps with its own clock is
    reported as another clock domain (an hour ahead it is also refused as from the future;
    behind, it would have been taken as a sample minutes old)."""
    host_offset_ns = HOUR_NS if other_host.startswith("up") else -(time.monotonic_ns() - 30 * S)
    beacon = RobotTimeBeacon(bus=robot_bus)
    aggregator = StateAggregator(bus=robot_bus)
    followed = RobotTimeClock(local_ns=shifted(host_offset_ns))
    async with beacon, aggregator:
        sender = await Bus.open(ConnectionOptions(robot=robot, connect=[endpoint]),
                                clock=followed)
        naive = await Bus.open(ConnectionOptions(robot=robot, connect=[endpoint]),
                               clock=OtherHostClock(host_offset_ns))
        try:
            subscription = followed.follow(sender)
            await eventually(lambda: followed.ready.is_set(), timeout_s=5,
                             what="the robot's clock on ubf/<robot>/time")
            # Learned: the robot's time, never ahead of it, and behind by latency only.
            before = time.monotonic_ns()
            seen = followed.now_ns()
            after = time.monotonic_ns()
            assert before - 50 * MS <= seen <= after, (seen - before) / 1e6

            good = sender.publisher(RANGE, "followed")
            bad = naive.publisher(RANGE, "naive")
            await good.wait_for_subscribers()
            await bad.wait_for_subscribers()
            good.publish({"range_mm": 300, "status": "ok"})
            bad.publish({"range_mm": 300, "status": "ok"})
            await eventually(lambda: aggregator.clock_domain.total >= 1
                             and any(s.source == "range/followed"
                                     for s in aggregator.sources()),
                             timeout_s=5, what="both samples at the robot")
            sources = {s.source: s for s in aggregator.sources()}
            assert 0 <= sources["range/followed"].age_s < 0.5
            assert not sources["range/followed"].stale
            foreign = {f["source"]: f for f in aggregator.clock_domain.status()}
            assert set(foreign) == {"range/naive"}
            assert foreign["range/naive"]["clock"] == "another clock"
            assert foreign["range/naive"]["offset_s"] == pytest.approx(host_offset_ns / S,
                                                                      abs=1.0)
            subscription.close()
        finally:
            await sender.aclose()
            await naive.aclose()


@pytest.mark.asyncio
async def test_auto_follows_the_robot_time_only_from_another_host(
    robot_bus: Bus, endpoint: str, robot: str
) -> None:
    """``follow_robot_clock(auto)``: a wall-time robot on this host is this host's clock;
    the same beacon naming another host is followed."""
    async with RobotTimeBeacon(bus=robot_bus) as beacon:
        peer = await Bus.open(ConnectionOptions(robot=robot, connect=[endpoint]))
        try:
            own = await follow.follow_robot_clock(peer, mode="auto", wait_s=2.0)
            assert own is peer.clock and not hasattr(own, "estimator")
            beacon.host = "robot-host-elsewhere"
            other = await follow.follow_robot_clock(peer, mode="auto", wait_s=2.0)
            assert isinstance(other, RobotTimeClock) and peer.clock is other
            assert other.host == "robot-host-elsewhere"
            assert abs(other.now_ns() - time.monotonic_ns()) < 50 * MS  # same host, in truth
            assert "robot host" in follow.describe(other, robot=robot)
        finally:
            await peer.aclose()


@pytest.mark.asyncio
async def test_a_wall_time_launch_publishes_its_clock(endpoint: str, robot: str) -> None:
    """The real launch path: a robot with no simulator (--no-sim) publishes ubf/<robot>/time
    about every 0.1 s, stamped on its CLOCK_MONOTONIC."""
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "ubf_async.launch", "--no-sim", "--robot", robot, "--listen",
        endpoint, "--quiet", stdout=asyncio.subprocess.PIPE)
    try:
        await read_until(proc, "controller:")
        bus = await Bus.open(ConnectionOptions(robot=robot, connect=[endpoint]))
        try:
            stamps: list[tuple[int, int]] = []
            bus.subscribe(ROBOT_TIME.key(bus.keys),
                          lambda k, p, t: stamps.append((decode(p, topic=ROBOT_TIME).stamp_ns,
                                                         t)), latest=False)
            await eventually(lambda: len(stamps) >= 6, timeout_s=5,
                             what="samples on ubf/<robot>/time")
            gaps = [(b[0] - a[0]) / 1e9 for a, b in itertools.pairwise(stamps)]
            assert all(0.05 < gap < 0.3 for gap in gaps), gaps
            assert all(0 <= received - stamp < 100 * MS for stamp, received in stamps)
        finally:
            await bus.aclose()
    finally:
        proc.terminate()
        await proc.wait()
