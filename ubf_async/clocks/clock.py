"""One clock for the whole robot: wall time, or simulation time published by a simulator.

Every stamp and every periodic wait in the runtime goes through a :class:`Clock`:

* :class:`WallClock` — ``CLOCK_MONOTONIC`` nanoseconds (``time.monotonic_ns()``), the same
  clock in every process of the host, so stamps carried in messages can be compared across
  processes.
* :class:`SimClock` — time that only moves when told to (:meth:`SimClock.advance_to`), by a
  simulator in the same process or by samples on ``ubf/<robot>/clock`` from one in another
  (like ROS's ``use_sim_time``). A simulator running K× faster than real time makes every
  component's periods, timeouts and latencies K× shorter in wall time, consistently.
  Which samples may move it is decided by :class:`ubf_async.clocks.timesource.ClockFollower`; a new
  simulation run *resets* it (:meth:`SimClock.reset_to`), and periodic loops re-anchor.

Simulated time is a lockstep barrier (:mod:`components.sim.runner.stepper`): it waits for the work
of each instant, so it may stand still for as long as that takes. Safety deadlines (the motor
watchdog, staleness) are therefore judged in robot time, and in wall time only when the time
source itself has gone silent — a simulator that died, not one that waits on purpose:
:class:`SilenceLimit` is the one rule they share (see its docstring for the numbers).
"""

from __future__ import annotations

import asyncio
import contextlib
import heapq
import itertools
import time
from collections.abc import AsyncIterator, Callable, Iterator
from dataclasses import dataclass
from typing import Protocol

__all__ = ["MIN_SILENCE_S", "Clock", "Hold", "NoHold", "SilenceLimit", "SimClock", "SimHold",
           "WallClock", "every", "sleep_until"]


class Hold(Protocol):
    def release(self) -> None:
        ...


class Clock(Protocol):
    is_simulated: bool
    """Whether time is simulated (moved by a simulator) rather than the host's or robot's."""
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
        """Wall seconds the clock's time source has been silent (0 for a clock that always
        runs, and for simulated time whose simulator is alive: see :class:`SimClock`)."""
        ...

    def describe(self, robot: str) -> str:
        """Which clock this is, for a process's start-up line (``robot``: whose keys)."""
        ...


class NoHold:
    """The hold of a clock that waits for nobody (wall time, a robot host's time)."""

    def release(self) -> None:
        pass


class WallClock:
    """Host monotonic time."""

    is_simulated = False
    resets = 0

    # The C function itself, not a method calling it: read several times per sample on the
    # reflex path, where a Python frame fewer is measurable (docs/latency.md).
    now_ns: Callable[[], int] = staticmethod(time.monotonic_ns)

    def stalled_s(self, wall_now_ns: int | None = None) -> float:
        """Wall time never stalls."""
        return 0.0

    def describe(self, robot: str) -> str:
        return "wall clock (CLOCK_MONOTONIC)"

    def hold(self, until_ns: int) -> Hold:
        """Real time waits for nobody: a no-op."""
        return NoHold()

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

    Whether the time source is alive (:meth:`stalled_s`): a simulator of this process
    declares itself with :meth:`driven` for as long as it runs; a follower hears it through
    its samples, which the simulator keeps sending while it waits on purpose
    (:meth:`advance_to` with the same time counts); a lockstep participant knows it from
    the simulator's session itself (:meth:`source_alive_while`).
    """

    is_simulated = True

    def __init__(self, start_ns: int = 0) -> None:
        self._now = start_ns
        self.resets = 0
        self._heard_wall_ns = time.monotonic_ns()
        self._drivers = 0
        self._alive_while: list[Callable[[], bool]] = []
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

    def next_wakeup_ns(self) -> int | None:
        """The earliest time a sleeper waits for, if any (a simulator of this process steps
        up to it without waking the loop: nothing of this process is due before it)."""
        sleepers = self._sleepers
        while sleepers and sleepers[0][2].done():  # cancelled sleepers: gone
            heapq.heappop(sleepers)
        return sleepers[0][0] if sleepers else None

    @contextlib.contextmanager
    def driven(self) -> Iterator[None]:
        """Declare, for the block's duration, that a simulator of this process drives the
        clock: however long it holds time still (a lockstep barrier, a slow render), its time
        source is alive and :meth:`stalled_s` is 0. When it ends — stopped or crashed — the
        silence is counted from then on."""
        self._drivers += 1
        try:
            yield
        finally:
            self._drivers -= 1
            self._heard_wall_ns = time.monotonic_ns()

    @contextlib.contextmanager
    def source_alive_while(self, alive: Callable[[], bool]) -> Iterator[None]:
        """Declare, for the block's duration, that the simulator this clock follows is alive
        whenever ``alive()`` says so — not judged by the wall time between its samples: a
        lockstep participant's simulator cannot move time without it, and its barrier's
        subscription to the participant's acknowledgements is there exactly as long as the
        simulator's session is (:class:`ubf_async.runtime.timekeepers.LockstepParticipant`).
        On a busy machine a simulator waiting on purpose may go unheard for longer than any
        wall-time limit; that must not decide what happens in simulated time. Once
        ``alive()`` says no (the simulator ended, died or was cut off), the silence counts
        from its last sample."""
        self._alive_while.append(alive)
        try:
            yield
        finally:
            self._alive_while.remove(alive)

    def describe(self, robot: str) -> str:
        return f"simulated time (ubf/{robot}/clock)"

    def stalled_s(self, wall_now_ns: int | None = None) -> float:
        """Wall seconds since the time source was last heard from: 0 while a simulator of
        this process drives the clock (:meth:`driven`), a hold of this process keeps it
        still on purpose, or the followed simulator is known to be alive
        (:meth:`source_alive_while`); otherwise since the last :meth:`advance_to` — a
        followed simulator sends its time every step, and again while it waits, so only a
        dead or cut-off simulator is silent."""
        if self._drivers or self._holds or any(alive() for alive in self._alive_while):
            return 0.0
        now = time.monotonic_ns() if wall_now_ns is None else wall_now_ns
        return max(0.0, (now - self._heard_wall_ns) / 1e9)

    def advance_to(self, now_ns: int) -> None:
        """Move time forward (never backward: an older time is ignored) and wake sleepers.
        The same time again is a sign of life of the time source (:meth:`stalled_s`)."""
        if now_ns > self._now:
            self._now = now_ns
        self._heard_wall_ns = time.monotonic_ns()
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
        self._heard_wall_ns = time.monotonic_ns()
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


MIN_SILENCE_S = 0.5
"""The shortest wall-time silence of a simulated clock's source that counts as a dead
simulator; see :class:`SilenceLimit`."""


@dataclass(frozen=True, slots=True)
class SilenceLimit:
    """The rule every safety deadline follows: something (a drive command, a sensor's
    samples) is overdue when nothing has been heard from it for

    (a) ``limit_s`` of **robot time** — the normal rule, the same at any simulation speed
        and on any machine; or
    (b) ``silence_s`` of **wall time while the clock's source is silent** — a simulator
        that died or was cut off (``clock.stalled_s()`` at least ``silence_s``): robot time
        would never get there. ``silence_s`` is ``max(limit_s, min_silence_s)``.

    On wall time (a) always comes first, so nothing changes there. A simulated clock may
    stand still for as long as its simulator's lockstep barrier waits — a slow render, a busy
    machine — and that is not silence: a simulator in the same process is alive while it runs
    (:meth:`SimClock.driven`), and one in another process keeps sending its time while it
    waits. So a live simulator is judged in simulated time only, however slowly it runs.
    ``min_silence_s`` keeps a follower in another process from taking a busy simulator's
    pause for its death; a lockstep participant does not judge by the pauses at all while
    the simulator's session is there (:meth:`SimClock.source_alive_while`): what it does
    then is part of a run that must not depend on wall time.
    """

    limit_s: float
    min_silence_s: float = MIN_SILENCE_S

    def __post_init__(self) -> None:
        if not self.limit_s > 0:
            raise ValueError(f"limit_s must be > 0, got {self.limit_s}")
        if not self.min_silence_s >= 0:
            raise ValueError(f"min_silence_s must be >= 0, got {self.min_silence_s}")

    @property
    def silence_s(self) -> float:
        """Rule (b)'s wall-time limit."""
        return max(self.limit_s, self.min_silence_s)

    def expired(self, clock: Clock, *, since_ns: int, since_wall_ns: int,
                now_ns: int | None = None, wall_now_ns: int | None = None) -> bool:
        """Whether the limit has passed since robot time ``since_ns`` / host monotonic time
        ``since_wall_ns`` (both taken when last heard from)."""
        return self.overdue(clock, since_ns=since_ns, since_wall_ns=since_wall_ns,
                            now_ns=now_ns, wall_now_ns=wall_now_ns) is not None

    def overdue(self, clock: Clock, *, since_ns: int, since_wall_ns: int,
                now_ns: int | None = None, wall_now_ns: int | None = None) -> str | None:
        """``None`` while the limit holds; once passed, the measure that passed it, in the
        clock it was measured in — what a warning says (``"112 ms of robot time (limit 110
        ms)"``, or the wall time with the clock's source silent)."""
        now = clock.now_ns() if now_ns is None else now_ns
        quiet_ms = (now - since_ns) / 1e6
        if quiet_ms >= self.limit_s * 1e3:
            return f"{quiet_ms:.0f} ms of robot time (limit {self.limit_s * 1e3:.0f} ms)"
        wall_now = time.monotonic_ns() if wall_now_ns is None else wall_now_ns
        silence = self.silence_s
        wall_s = (wall_now - since_wall_ns) / 1e9
        stalled = clock.stalled_s(wall_now)
        if wall_s >= silence and stalled >= silence:
            return (f"{wall_s:.2f} s of wall time with the clock's source silent for "
                    f"{stalled:.2f} s (limit {silence:g} s; {quiet_ms:.0f} ms of robot time)")
        return None

    def wall_deadline_ns(self, clock: Clock, *, since_wall_ns: int,
                         wall_now_ns: int | None = None) -> int:
        """The earliest host monotonic time at which (b) may hold, if robot time does not
        get there first: when to re-check."""
        wall_now = time.monotonic_ns() if wall_now_ns is None else wall_now_ns
        silence_ns = round(self.silence_s * 1e9)
        silent_since = wall_now - round(clock.stalled_s(wall_now) * 1e9)
        return max(since_wall_ns, silent_since) + silence_ns


async def sleep_until(clock: Clock, deadline_ns: int, *, wall_deadline_ns: int) -> None:
    """Sleep until robot time ``deadline_ns`` or host monotonic time ``wall_deadline_ns``,
    whichever comes first (or a reset of the clock wakes it).

    A cancellation is never lost, however it coincides with the robot-time sleep's end.
    (``asyncio.wait_for`` of Python 3.11 returns normally when it is cancelled after the
    sleep it waits for has ended but before its caller resumed, CPython gh-86296: a motors
    watchdog closed in that instant went on guarding, stopped the wheels 0.5 s after its
    simulator had closed and then waited for a drive command for ever, and so did the close
    that awaited it.)"""
    wall_s = (wall_deadline_ns - time.monotonic_ns()) / 1e9
    if wall_s <= 0:
        await asyncio.sleep(0)
        return
    sleeper = asyncio.ensure_future(clock.sleep_until_ns(deadline_ns))
    try:
        done, _ = await asyncio.wait({sleeper}, timeout=wall_s)
    finally:
        sleeper.cancel()  # the wall deadline came first, or this sleep was cancelled
    for ended in done:
        ended.result()
