"""One clock for the whole robot: wall time, or simulation time published by a simulator.

Every stamp and every periodic wait in the runtime goes through a :class:`Clock`:

* :class:`WallClock` — ``CLOCK_MONOTONIC`` nanoseconds (``time.monotonic_ns()``), the same
  clock in every process of the host, so stamps carried in messages can be compared across
  processes.
* :class:`SimClock` — time that only moves when told to (:meth:`SimClock.advance_to`), by a
  simulator in the same process or by samples on ``ubf/<robot>/clock`` from one in another
  (like ROS's ``use_sim_time``). A simulator running K× faster than real time makes every
  component's periods, timeouts and latencies K× shorter in wall time, consistently.
"""

from __future__ import annotations

import asyncio
import heapq
import itertools
import time
from collections.abc import AsyncIterator
from typing import Protocol


class Hold(Protocol):
    def release(self) -> None:
        ...


class Clock(Protocol):
    def now_ns(self) -> int:
        """The current robot time in nanoseconds."""
        ...

    def hold(self, until_ns: int) -> Hold:
        """Ask time not to pass ``until_ns`` before :meth:`Hold.release` (see SimClock)."""
        ...

    async def sleep_until_ns(self, deadline_ns: int) -> None:
        """Return once ``now_ns() >= deadline_ns``."""
        ...

    async def sleep(self, seconds: float) -> None:
        ...


class _NoHold:
    def release(self) -> None:
        pass


class WallClock:
    """Host monotonic time."""

    is_simulated = False

    def now_ns(self) -> int:
        return time.monotonic_ns()

    def hold(self, until_ns: int) -> Hold:
        """Real time waits for nobody: a no-op."""
        return _NoHold()

    async def sleep_until_ns(self, deadline_ns: int) -> None:
        # The event loop's own clock is also CLOCK_MONOTONIC on Linux, so call_at is exact.
        await asyncio.sleep(max(0.0, (deadline_ns - time.monotonic_ns()) / 1e9))

    async def sleep(self, seconds: float) -> None:
        await asyncio.sleep(max(0.0, seconds))


class SimHold:
    """A promise, taken by a component of the simulator's process, that simulated time will
    not pass ``until_ns`` before :meth:`release` — e.g. the camera while it renders a frame
    whose capture latency ends at ``until_ns``. Releasing twice is harmless."""

    def __init__(self, clock: SimClock, until_ns: int) -> None:
        self.until_ns = until_ns
        self._clock = clock
        self.released = False

    def release(self) -> None:
        if not self.released:
            self.released = True
            self._clock._release(self)


class SimClock:
    """Time advanced explicitly; sleepers wake when it passes their deadline.

    Must be used from one event loop: :meth:`advance_to` runs on the loop (the bus bridge
    delivers clock samples there). A simulator in the same process honours
    :meth:`hold`: it does not step past a held time until the hold is released, so work
    that takes wall time (rendering a camera frame) takes no simulated time, however fast
    the simulation runs.
    """

    is_simulated = True

    def __init__(self, start_ns: int = 0) -> None:
        self._now = start_ns
        self._sleepers: list[tuple[int, int, asyncio.Future[None]]] = []
        self._order = itertools.count()
        self._holds: list[SimHold] = []
        self._released: asyncio.Event | None = None
        self.started = asyncio.Event()
        """Set at the first :meth:`advance_to`: before that no simulator has spoken."""

    def hold(self, until_ns: int) -> SimHold:
        hold = SimHold(self, until_ns)
        self._holds.append(hold)
        return hold

    def _release(self, hold: SimHold) -> None:
        self._holds.remove(hold)
        if self._released is not None:
            self._released.set()

    def held_until_ns(self) -> int | None:
        """The earliest time a hold keeps simulated time from passing, if any."""
        return min((h.until_ns for h in self._holds), default=None)

    async def wait_for_holds(self, target_ns: int) -> None:
        """For the simulator: return once no hold forbids advancing to ``target_ns``."""
        while (held := self.held_until_ns()) is not None and held < target_ns:
            self._released = asyncio.Event()
            await self._released.wait()

    def now_ns(self) -> int:
        return self._now

    def advance_to(self, now_ns: int) -> None:
        """Move time forward (never backward: an older time is ignored) and wake sleepers."""
        if now_ns > self._now:
            self._now = now_ns
        self.started.set()
        sleepers = self._sleepers
        while sleepers and sleepers[0][0] <= self._now:
            _, _, future = heapq.heappop(sleepers)
            if not future.done():
                future.set_result(None)

    async def sleep_until_ns(self, deadline_ns: int) -> None:
        if deadline_ns <= self._now:
            await asyncio.sleep(0)
            return
        future: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        heapq.heappush(self._sleepers, (deadline_ns, next(self._order), future))
        await future

    async def sleep(self, seconds: float) -> None:
        await self.sleep_until_ns(self._now + int(max(0.0, seconds) * 1e9))


async def every(clock: Clock, period_s: float) -> AsyncIterator[int]:
    """Yield the clock's time now and then every ``period_s`` on a fixed schedule (absolute
    deadlines, so the period never drifts; a late wake-up is not made up with a burst)."""
    if not period_s > 0:
        raise ValueError(f"period_s must be > 0, got {period_s}")
    period_ns = round(period_s * 1e9)
    deadline = clock.now_ns()
    while True:
        yield clock.now_ns()
        deadline += period_ns
        now = clock.now_ns()
        if now >= deadline:  # overslept: skip the missed slots, keep the phase
            deadline += ((now - deadline) // period_ns + 1) * period_ns
        await clock.sleep_until_ns(deadline)
