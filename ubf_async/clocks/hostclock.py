"""The robot clock on another host: a published offset.

A robot on wall time stamps everything with its host's ``CLOCK_MONOTONIC`` — meaningless on
another host, whose monotonic clock started at another boot. So the robot publishes its clock:
its :class:`~ubf_async.runtime.timekeepers.RobotTimeBeacon` puts a sample on
``ubf/<robot>/time`` every :data:`BEACON_PERIOD_S`, stamped with its ``CLOCK_MONOTONIC``
(nothing is published when simulating: then ``ubf/<robot>/clock``, the simulated time, is the
robot clock everywhere).

A process on another host follows it with :class:`RobotTimeClock`: every sample gives
``stamp − local time of arrival`` = *offset − one-way latency*, so the **largest** of the recent
ones (a sliding window of :data:`WINDOW` samples, ≈ 5 s) is the offset less the smallest
latency seen — ``local monotonic + offset`` is then the robot's time, early by that latency
(≈ 0.1 ms on a LAN, never late: a sample it stamps is never from the robot's future). The
window follows the slow drift of two crystals; a jump of more than :data:`RESTART_S` (the
robot restarted on another boot, or another host took its name) starts the window afresh.

Why not zenoh's HLC timestamps: they are wall time (NTP64) made monotonic, meaningful across
hosts only as far as the hosts' wall clocks agree (NTP), and a robot's ages are on its
monotonic clock. The published offset needs nothing from the hosts' clocks and a plain
msgpack client can do the same in a few lines (``docs/protocol.md``, *The robot clock*).

Pure logic (:class:`OffsetEstimator`) is testable without a bus; the local clock is
injectable, so a test can give two sessions deliberately different clocks.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections import deque
from collections.abc import Callable

from ubf_async.clocks.clock import Hold, NoHold
from ubf_async.clocks.port import ClockBus, Closing
from ubf_async.wire.protocol import Message
from ubf_async.wire.topics import ROBOT_TIME, RobotTime

__all__ = ["BEACON_PERIOD_S", "RESTART_S", "WINDOW", "OffsetEstimator", "RobotTimeClock"]

log = logging.getLogger(__name__)

BEACON_PERIOD_S = 0.1
WINDOW = 50
"""Offset samples the estimate is the largest of (5 s of beacons)."""
RESTART_S = 1.0
"""An offset sample this far from the estimate starts a new window (a robot restarted)."""


class OffsetEstimator:
    """The robot clock's offset from a local clock, from ``(robot stamp, local arrival)``
    pairs: the largest ``stamp − arrival`` of the last ``window`` pairs (module docstring)."""

    def __init__(self, *, window: int = WINDOW, restart_s: float = RESTART_S) -> None:
        if window < 1:
            raise ValueError(f"window must be ≥ 1, got {window}")
        self.window: deque[int] = deque(maxlen=window)
        self.restart_ns = round(restart_s * 1e9)
        self.restarts = 0
        """Times the window was started afresh after a jump."""

    @property
    def ready(self) -> bool:
        return bool(self.window)

    @property
    def offset_ns(self) -> int:
        """``robot time − local time``; :class:`RuntimeError` before the first sample."""
        if not self.window:
            raise RuntimeError("no robot time sample yet")
        return max(self.window)

    @property
    def spread_ns(self) -> int:
        """Largest minus smallest offset sample in the window: the latency jitter seen."""
        return max(self.window) - min(self.window) if self.window else 0

    def offer(self, *, robot_stamp_ns: int, local_arrival_ns: int) -> None:
        sample = robot_stamp_ns - local_arrival_ns
        if self.window and abs(sample - max(self.window)) > self.restart_ns:
            self.window.clear()
            self.restarts += 1
        self.window.append(sample)


class RobotTimeClock:
    """The robot's ``CLOCK_MONOTONIC`` seen from another host: the local monotonic clock
    (``local_ns``, injectable) plus the offset :class:`OffsetEstimator` learns from
    ``ubf/<robot>/time``. A :class:`~ubf_async.clocks.clock.Clock`: give it to a bus
    (``bus.clock = clock``) and everything that bus stamps is on the robot clock.

    :meth:`follow` subscribes; :attr:`ready` is set at the first sample (``now_ns()`` raises
    before it)."""

    is_simulated = False
    resets = 0

    def __init__(self, *, local_ns: Callable[[], int] = time.monotonic_ns,
                 estimator: OffsetEstimator | None = None) -> None:
        self.local_ns = local_ns
        self.estimator = estimator if estimator is not None else OffsetEstimator()
        self.ready = asyncio.Event()
        self.host: str | None = None
        """The robot's host, as its beacon names it."""
        self.malformed: dict[str, int] = {}

    def now_ns(self) -> int:
        return self.local_ns() + self.estimator.offset_ns

    def hold(self, until_ns: int) -> Hold:
        return NoHold()

    def stalled_s(self, wall_now_ns: int | None = None) -> float:
        return 0.0

    def describe(self, robot: str) -> str:
        return f"the robot host's clock (ubf/{robot}/time, offset learned)"

    async def sleep_until_ns(self, deadline_ns: int) -> None:
        await asyncio.sleep(max(0.0, (deadline_ns - self.now_ns()) / 1e9))

    async def sleep(self, seconds: float) -> None:
        await asyncio.sleep(max(0.0, seconds))

    def follow(self, bus: ClockBus) -> Closing:
        """Learn the offset from ``bus``'s robot's ``ubf/<robot>/time`` samples."""

        def on_sample(key: str, message: Message[RobotTime], received_ns: int) -> None:
            # The bridge stamped the arrival on CLOCK_MONOTONIC; carry it to the local clock.
            # CLOCK_MONOTONIC is read first: a pause between the two reads then makes the
            # arrival later and the estimate early, never ahead of the robot's time.
            since_arrival_ns = time.monotonic_ns() - received_ns
            arrival = self.local_ns() - since_arrival_ns
            self.estimator.offer(robot_stamp_ns=message.stamp_ns, local_arrival_ns=arrival)
            self.host = message.data.host
            self.ready.set()

        return bus.subscribe_topic(ROBOT_TIME.key(bus.keys), ROBOT_TIME, on_sample, self.malformed,
                                   latest=False)
