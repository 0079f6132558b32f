"""One clock for the whole robot: wall time, or simulation time published by a simulator.

Every stamp and every periodic wait in the runtime goes through a :class:`Clock`:

* :class:`WallClock` — ``CLOCK_MONOTONIC`` nanoseconds (``time.monotonic_ns()``), the same
  clock in every process of the host, so stamps carried in messages can be compared across
  processes.
* :class:`SimClock` — time that only moves when told to (:meth:`SimClock.advance_to`), by a
  simulator in the same process or by samples on ``ubf/<robot>/clock`` from one in another
  (like ROS's ``use_sim_time``). A simulator running K× faster than real time makes every
  component's periods, timeouts and latencies K× shorter in wall time, consistently.
  Which samples may move it is decided by :class:`ubf_async.timesource.ClockFollower`; a new
  simulation run *resets* it (:meth:`SimClock.reset_to`), and periodic loops re-anchor.

Safety deadlines (the motor watchdog, staleness) must also hold when simulated time stops:
:class:`SilenceLimit` is the one rule they share — robot time, or wall time while the clock
is stalled, or a wall-time backstop (see its docstring for the numbers).
"""

from __future__ import annotations

import asyncio
import contextlib
import heapq
import itertools
import time
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass
from typing import Protocol


class Hold(Protocol):
    def release(self) -> None:
        ...


class Clock(Protocol):
    resets: int
    """How many times the clock was reset to a new run's time (0 for wall time). Periodic
    loops compare it before and after a sleep and re-anchor their deadlines when it changed."""

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

    def stalled_s(self, wall_now_ns: int | None = None) -> float:
        """Wall seconds since the clock last advanced (0 for a clock that always runs)."""
        ...


class _NoHold:
    def release(self) -> None:
        pass


class WallClock:
    """Host monotonic time."""

    is_simulated = False
    resets = 0

    def now_ns(self) -> int:
        return time.monotonic_ns()

    def stalled_s(self, wall_now_ns: int | None = None) -> float:
        """Wall time never stalls."""
        return 0.0

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
        self.resets = 0
        self._advanced_wall_ns = time.monotonic_ns()
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

    def stalled_s(self, wall_now_ns: int | None = None) -> float:
        """Wall seconds since time last advanced — 0 while a hold of this process keeps it
        still on purpose (the simulator waiting for a camera frame is not a stall)."""
        if self._holds:
            return 0.0
        now = time.monotonic_ns() if wall_now_ns is None else wall_now_ns
        return max(0.0, (now - self._advanced_wall_ns) / 1e9)

    def advance_to(self, now_ns: int) -> None:
        """Move time forward (never backward: an older time is ignored) and wake sleepers."""
        if now_ns > self._now:
            self._now = now_ns
            self._advanced_wall_ns = time.monotonic_ns()
        self.started.set()
        sleepers = self._sleepers
        while sleepers and sleepers[0][0] <= self._now:
            _, _, future = heapq.heappop(sleepers)
            if not future.done():
                future.set_result(None)

    def reset_to(self, now_ns: int) -> None:
        """Start a new run at ``now_ns`` (which may be earlier than the current time): count
        the reset in :attr:`resets` and wake **every** sleeper — their deadlines belong to the
        old run; each wakes early, sees :attr:`resets` changed and re-anchors."""
        self._now = now_ns
        self.resets += 1
        self._advanced_wall_ns = time.monotonic_ns()
        self.started.set()
        sleepers, self._sleepers = self._sleepers, []
        for _, _, future in sleepers:
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


async def every(clock: Clock, period_s: float, *,
                on_overrun: Callable[[], None] | None = None) -> AsyncIterator[int]:
    """Yield the clock's time now and then every ``period_s`` on a fixed schedule (absolute
    deadlines, so the period never drifts; a late wake-up is not made up with a burst: the
    missed slots are skipped, and ``on_overrun()`` is called once for them).

    When the clock is reset to a new run (:attr:`Clock.resets` changes), the schedule is
    re-anchored on the new run's time: one yield at once, then every ``period_s`` from there."""
    if not period_s > 0:
        raise ValueError(f"period_s must be > 0, got {period_s}")
    period_ns = round(period_s * 1e9)
    deadline = clock.now_ns()
    resets = clock.resets
    while True:
        yield clock.now_ns()
        if clock.resets != resets:  # a new run: its time, not the old run's, sets the phase
            resets = clock.resets
            deadline = clock.now_ns()
        deadline += period_ns
        now = clock.now_ns()
        if now >= deadline:  # overslept: skip the missed slots, keep the phase
            deadline += ((now - deadline) // period_ns + 1) * period_ns
            if on_overrun is not None:
                on_overrun()
        await clock.sleep_until_ns(deadline)


MIN_REAL_TIME_FACTOR = 0.2
"""The slowest simulation (simulated seconds per wall second) that safety deadlines still
measure in robot time alone; see :class:`SilenceLimit`."""


@dataclass(frozen=True, slots=True)
class SilenceLimit:
    """The rule every safety deadline follows: something (a drive command, a sensor's
    samples) is overdue when nothing has been heard from it for

    (a) ``limit_s`` of **robot time** — the normal rule, consistent at any simulation speed;
    (b) ``limit_s`` of **wall time while the clock is stalled** — it has not advanced for
        ``limit_s`` of wall time either (the simulator stopped, died or is being refused):
        robot time would never get there;
    (c) ``limit_s / min_real_time_factor`` of **wall time** in any case — a backstop for a
        clock that crawls.

    With wall time (a) always comes first, so nothing changes there. Why a simulation running
    slowly is not cut off: a simulator publishes its clock every step (5 ms of simulated
    time), i.e. every 25 ms of wall time at 0.2× real time, far inside any ``limit_s`` of
    tens of milliseconds or more, so (b) never holds while it runs; and a 50 Hz controller
    at 0.2× sends a command every 100 ms of wall time, far inside (c)'s 5 × ``limit_s``.
    """

    limit_s: float
    min_real_time_factor: float = MIN_REAL_TIME_FACTOR

    def __post_init__(self) -> None:
        if not self.limit_s > 0:
            raise ValueError(f"limit_s must be > 0, got {self.limit_s}")
        if not 0 < self.min_real_time_factor <= 1:
            raise ValueError("min_real_time_factor must be in (0, 1], got "
                             f"{self.min_real_time_factor}")

    @property
    def backstop_s(self) -> float:
        """Rule (c)'s wall-time limit."""
        return self.limit_s / self.min_real_time_factor

    def expired(self, clock: Clock, *, since_ns: int, since_wall_ns: int,
                now_ns: int | None = None, wall_now_ns: int | None = None) -> bool:
        """Whether the limit has passed since robot time ``since_ns`` / host monotonic time
        ``since_wall_ns`` (both taken when last heard from)."""
        now = clock.now_ns() if now_ns is None else now_ns
        wall_now = time.monotonic_ns() if wall_now_ns is None else wall_now_ns
        if now - since_ns >= self.limit_s * 1e9:
            return True
        quiet_wall_s = (wall_now - since_wall_ns) / 1e9
        if quiet_wall_s >= self.backstop_s:
            return True
        return quiet_wall_s >= self.limit_s and clock.stalled_s(wall_now) >= self.limit_s

    def wall_deadline_ns(self, clock: Clock, *, since_wall_ns: int,
                         wall_now_ns: int | None = None) -> int:
        """The earliest host monotonic time at which (b) or (c) may hold, if robot time does
        not get there first: when to re-check."""
        wall_now = time.monotonic_ns() if wall_now_ns is None else wall_now_ns
        limit_ns = round(self.limit_s * 1e9)
        stalled_since = wall_now - round(clock.stalled_s(wall_now) * 1e9)
        by_stall = max(since_wall_ns, stalled_since) + limit_ns
        return min(by_stall, since_wall_ns + round(self.backstop_s * 1e9))


async def sleep_until(clock: Clock, deadline_ns: int, *, wall_deadline_ns: int) -> None:
    """Sleep until robot time ``deadline_ns`` or host monotonic time ``wall_deadline_ns``,
    whichever comes first (or a reset of the clock wakes it)."""
    wall_s = (wall_deadline_ns - time.monotonic_ns()) / 1e9
    if wall_s <= 0:
        await asyncio.sleep(0)
        return
    with contextlib.suppress(TimeoutError):
        await asyncio.wait_for(clock.sleep_until_ns(deadline_ns), wall_s)
