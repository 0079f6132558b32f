"""The UBF controller: ticks the root behaviour and publishes the arbitrated action.

Three ways to decide *when* to tick (:class:`TickMode`):

* ``periodic`` (default) — on its own clock at ``rate_hz`` (default 50 Hz), whatever the
  sensors do. A slow camera never holds back a fast IR reflex. Sources matching
  ``reflex_sources`` (prefixes such as ``"range/"``) also tick it at once when a sample
  arrives, so an obstacle is answered in about a millisecond, not half a period. Reflex
  ticks are rate-limited together by a token bucket (``reflex_rate_hz``, default
  0.8 × ``rate_hz``, burst ``reflex_burst``, robot clock): a reflex source flooding the
  robot cannot make it command more than ``rate_hz + reflex_rate_hz`` (1.8 × ``rate_hz``)
  times a second, with a margin below twice its rate; a sample
  that finds the bucket empty is used by the next tick instead (counted in
  ``reflex_limited``).
* ``sync`` — the thesis's loop: every tick first waits for a *new* sample of
  ``sync_source`` (default ``"camera/front"``), as the Mini-WHEGS's state update waited for
  an image capture. Kept so the two can be compared.
* ``event`` — tick whenever a chosen source (``trigger``) delivers a new sample.

Triggered ticks (reflexes, ``sync``, ``event``) run right where the aggregator stores the
sample, with no extra pass through the event loop. On a wall-clock robot they do not wait
for the loop at all: the **reflex lane** (``lane=True``, the default; a robot file's
``controller: {lane: false}`` turns it off) stores a sample of a source that ticks the
controller, and runs that tick, on the transport's thread that brought it, while the loop
sleeps (:meth:`StateAggregator.open_lane
<ubf_async.runtime.aggregator.StateAggregator.open_lane>`). Behaviours, arbiters and the
aggregator are still never run by two threads at once: the lane and the loop's ticks, holds,
status and tree changes all hold the aggregator's :attr:`lock` — one at a time, in the order
they took it. So a behaviour needs no locks of its own, but it must not call the event loop
from ``act`` (no ``asyncio.get_running_loop()``, no task created): with the lane it may run
on another thread. A tree that must run on the loop thread says ``lane: false``. Lockstep
and simulated time never take the lane (their order is simulated time's, kept on the loop).

Each tick takes a :class:`~ubf_async.core.state.State` snapshot from the aggregator (with the
previous tick's published action in ``previous_action``), evaluates the root behaviour,
and publishes:

* ``cmd/drive`` every tick: speed and turn (an unset field, or no action at all, means 0 —
  a robot without an opinion stands still), the tick number, the leaf behaviours that won,
  and ``based_on``: the source, seq and stamp of the sample the tick was based on (the
  trigger in ``sync``/``event`` mode, the newest sample in ``periodic`` mode), so latency
  can be measured end to end;
* ``cmd/seek_color``, ``cmd/radio``, ``cmd/leds`` when the action sets them to a new value;
* ``trace`` after the command, while anyone subscribes to it (a recorder, a viewer): the
  tick's behaviours depth first, with who won and what each proposed (``TickTrace``). With no
  subscriber it costs one check.

Lifecycle of the tree (the hooks are described in :mod:`ubf_async.core.behavior`): each time the
component runs — its start, and again after a restart — the controller calls
``root.setup()`` once, then ``root.reset()``, before its first tick; an exception from setup
fails that run like any other (logged, restarted with backoff) and no tick happens. When the
run ends, however it ends, the controller calls ``root.shutdown()``.

A tick never fails because of its input. Whatever it copies from input into the command
(``based_on.source``, ``winners``) is cut to what the protocol carries
(:func:`~ubf_async.wire.protocol.clip`). A behaviour or arbiter below the root that raises is cut
off for that tick and, if it keeps failing, quarantined by its composite (see
:mod:`ubf_async.core.behavior`; ``status()["quarantined"]`` lists them); if the root itself
raises, the failure is logged, counted in ``errors``, and that tick commands a stop. If
publishing the command still raises, it is counted in ``publish_errors``, logged, and a
plain stop is published instead. A fault anywhere else in a tick (the snapshot, the
bookkeeping, an observer's hook) is contained too: counted in ``tick_faults``, logged, a stop
commanded, and the decision a hold repeats is that stop — never the last one from before the
fault. The next tick runs as usual: the tick a sample runs is not a droppable observer of the
aggregator, it cannot raise out of :meth:`Controller._on_sample`.
A tick that ends after the next tick was due counts as an overrun; missed ticks are skipped,
not bunched up.

Observers (recorders, benchmarks, tests) use :meth:`Controller.on_tick` and the aggregator's
hooks (:meth:`~ubf_async.runtime.aggregator.StateAggregator.on_sample` and the others), not
subclasses or a wrapped ``publish``.
"""

from __future__ import annotations

import asyncio
import enum
import itertools
import logging
import socket
import statistics
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, ClassVar

from ubf_async import throttle
from ubf_async.clocks.clock import Clock, WallClock, every
from ubf_async.core.action import Action
from ubf_async.core.behavior import Behavior, Composite, Trace
from ubf_async.core.state import State
from ubf_async.runtime.aggregator import SourceEntry, StateAggregator
from ubf_async.runtime.bus import Bus
from ubf_async.runtime.component import Component
from ubf_async.runtime.hooks import add_hook, run_hooks
from ubf_async.runtime.ratelimit import TokenBucket
from ubf_async.wire.protocol import clip
from ubf_async.wire.topics import (
    CONTROLLER_STATUS,
    DRIVE,
    LEDS,
    MAX_NAME_CHARS,
    MAX_TRACE_NODES,
    MAX_TREE_DEPTH,
    MAX_WINNERS,
    RADIO_SEND,
    SEEK_COLOR,
    TRACE,
    BasedOn,
    Drive,
    Leds,
    RadioSend,
    SeekColor,
    TickedBy,
    TickTrace,
    TraceNode,
)

__all__ = ["DEFAULT_NAME", "MAX_COUNTED_NAMES", "MAX_EXPLANATION_CHARS", "REFLEX_SHARE",
           "Controller", "TickHook", "TickMode", "TickStats", "outgoing_names", "trace_nodes"]

log = logging.getLogger(__name__)

DEFAULT_NAME = "controller"
"""A controller's component name unless given one (its status and liveliness keys carry it)."""

TickHook = Callable[[State, Trace | None, Any], None]
"""``callback(state, trace, command)`` after a tick's drive command went out
(:meth:`Controller.on_tick`)."""

MAX_EXPLANATION_CHARS = 4000
REFLEX_SHARE = 0.8
"""Default reflex tick budget as a share of ``rate_hz``."""
MAX_COUNTED_NAMES = 1024
"""Distinct behaviour names counted in ``winner_ticks`` (later newcomers are not counted)."""


def outgoing_names(names: list[str]) -> list[str]:
    """Behaviour names as a drive command may carry them (count and length bounded)."""
    names = names[:MAX_WINNERS]
    for name in names:  # (a plain loop, no comprehension: every tick asks, almost never cut)
        if len(name) > MAX_NAME_CHARS:
            return [clip(name, MAX_NAME_CHARS) for name in names]
    return names


def trace_nodes(trace: Trace) -> tuple[TraceNode, ...]:
    """One tick's trace as the ``trace`` topic carries it: depth first, names clipped, at most
    :data:`~ubf_async.wire.topics.MAX_TRACE_NODES` behaviours."""
    nodes: list[TraceNode] = []
    stack = [(trace, 0)]
    while stack and len(nodes) < MAX_TRACE_NODES:
        node, depth = stack.pop()
        action = node.action
        nodes.append(TraceNode(
            name=clip(node.name, MAX_NAME_CHARS), depth=min(depth, MAX_TREE_DEPTH),
            won=node.won, arbiter=node.arbiter and clip(node.arbiter, MAX_NAME_CHARS),
            speed=action.speed if action is not None else None,
            turn=action.turn if action is not None else None,
            vote=action.vote if action is not None else None,
            fault=node.fault and clip(node.fault, 256)))
        stack.extend((child, depth + 1) for child in reversed(node.children))
    return tuple(nodes)


def _no_lane() -> None:
    """The closer of a lane never opened."""


def _never(source: str) -> bool:
    """No source ticks a periodic controller without reflexes."""
    return False


class TickMode(enum.StrEnum):
    PERIODIC = "periodic"
    SYNC = "sync"
    EVENT = "event"


_TICKED_BY: dict[TickMode, TickedBy] = {
    TickMode.PERIODIC: "reflex", TickMode.SYNC: "sync", TickMode.EVENT: "event"}
"""What a tick run by a sample says ran it (``Drive.ticked_by``), per mode."""


@dataclass
class TickStats:
    ticks: int = 0
    triggered: int = 0
    """Ticks run by a sample (reflex, sync or event) rather than the clock."""
    periodic: int = 0
    """Ticks run by the clock."""
    overruns: int = 0
    errors: int = 0
    """Ticks on which the root behaviour raised (each commanded a stop)."""
    publish_errors: int = 0
    """Ticks whose command could not be published (a plain stop went out instead)."""
    tick_faults: int = 0
    """Ticks that failed outside the behaviour tree (each commanded a stop: module
    docstring)."""
    reflex_limited: int = 0
    """Reflex samples that did not tick because the reflex bucket was empty."""
    holds: int = 0
    """Drive commands repeating the last decision between triggered ticks (sync/event)."""
    periodic_starts_ns: deque[int] = field(default_factory=lambda: deque(maxlen=1000))
    """Robot-clock start time of recent ticks not run by a sample."""
    periodic_wall_ns: deque[int] = field(default_factory=lambda: deque(maxlen=1000))
    """Wall-clock (``perf_counter_ns``) start of the same ticks: their jitter in real time."""
    tick_ns: deque[int] = field(default_factory=lambda: deque(maxlen=1000))
    """How long recent ticks took (snapshot, evaluate, publish)."""
    tick_starts_ns: deque[int] = field(default_factory=lambda: deque(maxlen=1000))
    """Robot-clock start time of recent ticks."""
    winner_ticks: Counter[str] = field(default_factory=Counter)
    """How many ticks each leaf behaviour was among the winners."""

    @staticmethod
    def _rate(starts: deque[int]) -> float | None:
        if len(starts) < 2 or starts[-1] == starts[0]:
            return None
        return (len(starts) - 1) / ((starts[-1] - starts[0]) / 1e9)

    def rate_hz(self) -> float | None:
        return self._rate(self.tick_starts_ns)

    def periodic_rate_hz(self) -> float | None:
        """Rate of the recent ticks run by the clock (reflex ticks left out)."""
        return self._rate(self.periodic_starts_ns)

    def new_run(self) -> None:
        """Forget the recent ticks' times: the clock was reset to a new run (a rate across
        the reset would measure the jump, not the ticks)."""
        self.tick_starts_ns.clear()
        self.periodic_starts_ns.clear()
        self.periodic_wall_ns.clear()

    @staticmethod
    def _jitter_ms_p99(starts: deque[int]) -> float | None:
        """p99 of how far the intervals between ``starts`` stray from their median (ms)."""
        if len(starts) < 3:
            return None
        gaps = [b - a for a, b in itertools.pairwise(starts)]
        middle = statistics.median(gaps)
        strays = sorted(abs(gap - middle) for gap in gaps)
        return strays[min(len(strays) - 1, round(0.99 * (len(strays) - 1)))] / 1e6

    def periodic_jitter_ms_p99(self) -> float | None:
        """The recent ticks of the clock: their jitter in real time (wall-clock intervals),
        whatever the clock's rate."""
        return self._jitter_ms_p99(self.periodic_wall_ns)

    def periodic_jitter_robot_ms_p99(self) -> float | None:
        """The same ticks' jitter in robot time: 0 in a simulation in lockstep, however
        busy the machine."""
        return self._jitter_ms_p99(self.periodic_starts_ns)

    def summary(self) -> dict[str, Any]:
        durations = list(self.tick_ns)
        return {
            "ticks": self.ticks,
            "triggered": self.triggered,
            "overruns": self.overruns,
            "errors": self.errors,
            "publish_errors": self.publish_errors,
            "tick_faults": self.tick_faults,
            "reflex_limited": self.reflex_limited,
            "holds": self.holds,
            "rate_hz": self.rate_hz(),
            "periodic_rate_hz": self.periodic_rate_hz(),
            "periodic_jitter_ms_p99": self.periodic_jitter_ms_p99(),
            "periodic_jitter_robot_ms_p99": self.periodic_jitter_robot_ms_p99(),
            "tick_us_p50": statistics.median(durations) / 1e3 if durations else None,
            "tick_us_max": max(durations) / 1e3 if durations else None,
            "winner_share": {
                clip(name): count / self.ticks
                for name, count in sorted(self.winner_ticks.items())
            } if self.ticks else {},
        }


class Controller(Component):
    def __init__(
        self,
        *,
        bus: Bus,
        aggregator: StateAggregator,
        root: Behavior,
        rate_hz: float = 50.0,
        mode: TickMode | str = TickMode.PERIODIC,
        sync_source: str = "camera/front",
        trigger: str | None = None,
        reflex_sources: tuple[str, ...] = (),
        reflex_rate_hz: float | None = None,
        reflex_burst: int = 2,
        lane: bool = True,
        status_period_s: float = 0.5,
        status_clock: Clock | None = None,
        name: str = DEFAULT_NAME,
        **component_options: float,
    ) -> None:
        """``lane``: run triggered ticks on the reflex lane on a wall-clock robot (module
        docstring). ``status_clock``: what the status period is measured on — wall time by default
        (what people and tools watch, even while a simulation stands still); the robot's
        clock for a controller in a lockstep run, so that each status is of a simulated
        instant, the same at any speed (a fleet's world collects them)."""
        super().__init__(bus=bus, name=name, **component_options)
        if not rate_hz > 0:
            raise ValueError(f"rate_hz must be > 0, got {rate_hz}")
        self.mode = TickMode(mode)
        if self.mode is TickMode.EVENT and not trigger:
            raise ValueError("event mode needs a trigger source, e.g. trigger='range/front'")
        self.aggregator = aggregator
        self.lock = aggregator.lock
        """The aggregator's lock: held for every tick, hold, status and tree change, on the
        loop or on the reflex lane (module docstring)."""
        self.lane = lane
        self.root = root
        self.rate_hz = rate_hz
        self.sync_source = sync_source
        """The source whose every new sample ticks the controller in ``sync`` mode."""
        self.trigger = trigger
        self.reflex_sources = tuple(reflex_sources)
        self.reflex_rate_hz = (REFLEX_SHARE * rate_hz if reflex_rate_hz is None
                               else reflex_rate_hz)
        self.reflex_burst = reflex_burst
        self._reflex_bucket = TokenBucket(rate_hz=self.reflex_rate_hz, burst=reflex_burst,
                                          now_ns=bus.clock.now_ns())
        self._triggers = self._triggering_sources()
        self.status_period_s = status_period_s
        self.status_clock: Clock = status_clock if status_clock is not None else WallClock()
        self.host = socket.gethostname()[:253]
        """This host's name, in the status: with ``clock`` it tells a process attaching which
        clock to stamp with (:func:`ubf_async.clocks.follow.follow_robot_clock`)."""
        self.stats = TickStats()
        self.tree_changes: list[dict[str, Any]] = []
        """Live changes of the tree applied during the run (:meth:`tree_changed`)."""
        self._clock_resets = bus.clock.resets
        self.last_action: Action | None = None
        self._last_drive_ns = 0
        self.last_trace: Trace | None = None
        self.ticked = asyncio.Event()
        """Set after every tick (tests and tools clear and await it)."""
        self._sent: dict[str, Any] = {}
        self._tick_hooks: list[TickHook] = []

    def on_tick(self, callback: TickHook) -> Callable[[], None]:
        """Call ``callback(state, trace, command)`` after every tick, right after its drive
        command was published; returns a remover.

        ``state`` is the snapshot the tree evaluated, ``trace`` its trace (``None`` if the
        root raised) and ``command`` the drive data actually sent — the plain stop when the
        tick's own command could not be published. It runs for every call of :meth:`tick`:
        clock ticks, reflex ticks and the triggered ticks of ``sync`` and ``event`` mode
        (inside the aggregator's :meth:`~ubf_async.runtime.aggregator.StateAggregator.on_sample`,
        so still before anything else runs on the loop). It does **not** run for the holds
        of ``sync``/``event`` mode: a hold repeats the last decision without a state or an
        evaluation (counted in ``stats.holds``; watch ``cmd/drive`` to see every command).
        It runs before the tick publishes ``seek_color``/``radio``/``leds`` and before
        ``last_action``, ``last_trace``, ``stats.tick_ns`` and ``ticked`` are updated
        (``stats.ticks`` and ``stats.periodic`` already count the tick), so the time it
        reads is when the command left. Hooks run in the order they were added, where the
        tick runs — on the event loop, or on the reflex lane's thread (holding :attr:`lock`,
        never beside another tick; hand anything for the loop over with
        :meth:`Bus.call_on_loop <ubf_async.runtime.bus.Bus.call_on_loop>`): keep them
        short, a slow hook delays the tick's end. A hook that raises
        is logged and removed; the tick and the controller go on. With no hook a tick pays
        one truth test."""
        return add_hook(self._tick_hooks, callback)

    async def run(self) -> None:
        periodic = self.mode is TickMode.PERIODIC
        # Trusted: every drive command is built valid here (speed and turn from a validated
        # Action, names clipped, based_on from a validated sample), so it is not checked again.
        self._drive = self.publisher(DRIVE, period_s=1.0 / self.rate_hz if periodic else None,
                                     trusted=True)
        self._extras = {
            "seek_color": self.publisher(SEEK_COLOR),
            "message": self.publisher(RADIO_SEND),
            "leds": self.publisher(LEDS),
        }
        self._status = self.publisher(CONTROLLER_STATUS, self.name,
                                      period_s=self.status_period_s)
        self._trace = self.publisher(TRACE)
        self._sent = {}
        loop = {
            TickMode.PERIODIC: self._run_periodic,
            TickMode.SYNC: self._run_triggered,
            TickMode.EVENT: self._run_triggered,
        }[self.mode]
        try:
            with self.lock:
                self.root.setup()
                self.root.reset()
                remove_listener = self.aggregator.on_sample(self._on_sample)
                close_lane = (self.aggregator.open_lane(self._triggers) if self.lane
                              else _no_lane)
            try:
                async with asyncio.TaskGroup() as group:
                    group.create_task(self._publish_status())
                    group.create_task(loop())
            finally:
                with self.lock:  # waits for a tick on the lane to end: none after it
                    close_lane()
                    remove_listener()
        finally:
            try:
                with self.lock:
                    self.root.shutdown()
            except Exception:  # must not replace the exception (or cancellation) ending run
                log.exception("shutdown of the behaviour tree %r raised", self.root.name)

    async def _run_periodic(self) -> None:
        # every() re-anchors on a new simulation run's time, not the old run's deadline.
        async for _ in every(self.bus.clock, 1.0 / self.rate_hz,
                             on_overrun=self._count_overrun):
            self.tick()

    def _count_overrun(self) -> None:
        self.stats.overruns += 1

    def _triggering_sources(self) -> Callable[[str], bool]:
        """Whether a sample of a source ticks the controller (its mode's rule), as one call:
        the reflex lane asks it of every sample on the transport's thread."""
        if self.mode is TickMode.SYNC:
            return self.sync_source.__eq__
        if self.mode is TickMode.EVENT:
            assert self.trigger is not None  # (checked in __init__)
            return self.trigger.__eq__
        prefixes = self.reflex_sources
        return (lambda source: source.startswith(prefixes)) if prefixes else _never

    def _on_sample(self, source: str, entry: SourceEntry) -> None:
        # Contained whole: a sample hook that raises is dropped by the aggregator, and a
        # controller unhooked would never tick on a sample again.
        try:
            if not self._triggers(source):
                return
            if (self.mode is TickMode.PERIODIC
                    and not self._reflex_bucket.take(self.bus.clock.now_ns())):
                self.stats.reflex_limited += 1
                return
            self.stats.triggered += 1
        except Exception:
            self._tick_failed(None)
            return
        self._tick(entry)  # (inside ingest: the lock is held)

    async def _run_triggered(self) -> None:
        """Ticks come from :meth:`_on_sample`. Between them the last decision is repeated
        every ``1/rate_hz`` as a *hold* (``hold: true``, no ``based_on``, the same tick
        number), as the thesis robot's motors kept their last setting until the next image:
        the motors' watchdog (shorter than a camera period) must only stop a robot whose
        controller died. A hold while the trigger source is stale is a stop."""
        clock = self.bus.clock
        period_s = 1.0 / self.rate_hz
        period_ns = int(period_s * 1e9)
        trigger = self.sync_source if self.mode is TickMode.SYNC else self.trigger
        while True:
            await clock.sleep(period_s)
            with self.lock:
                self._hold(clock.now_ns(), period_ns, trigger)

    def _hold(self, now: int, period_ns: int, trigger: str | None) -> None:
        """Repeat the last decision unless a tick published lately (:meth:`_run_triggered`)."""
        if 0 <= now - self._last_drive_ns < period_ns:
            return  # a tick published lately (a clock that went back re-anchors here)
        fresh = trigger is not None and self.aggregator.fresh(trigger, now)
        last = self.last_action if fresh else None  # a tick always sets both fields
        trace = self.last_trace if fresh else None
        self.stats.holds += 1
        try:
            self._drive.publish(Drive(
                speed=last.speed if last and last.speed is not None else 0.0,
                turn=last.turn if last and last.turn is not None else 0.0,
                tick=self.stats.ticks, hold=True,
                winners=tuple(outgoing_names(trace.winning_leaves() if trace else [])),
            ))
        except Exception:
            self._publish_failed("hold drive command")
        self._last_drive_ns = now

    def tick(self, *, based_on: SourceEntry | None = None) -> Trace | None:
        """One UBF cycle: snapshot, evaluate, publish (holding :attr:`lock`)."""
        with self.lock:
            return self._tick(based_on)

    def _tick(self, based_on: SourceEntry | None) -> Trace | None:
        """:meth:`_run_tick`, its faults contained (module docstring): never raises."""
        try:
            return self._run_tick(based_on)
        except Exception:
            self._tick_failed(based_on)
            return None

    def _tick_failed(self, based_on: SourceEntry | None) -> None:
        """A tick failed outside the tree: count it, say so, command a stop, and make the
        stop what a hold repeats."""
        stats = self.stats
        stats.tick_faults += 1
        if throttle.first_and_every(stats.tick_faults):
            log.exception("a tick failed outside the behaviour tree (fault #%d): commanding "
                          "a stop", stats.tick_faults)
        self.last_action = Action(speed=0.0, turn=0.0)
        self.last_trace = None
        try:
            self._drive.publish(Drive(speed=0.0, turn=0.0, tick=stats.ticks,
                                      ticked_by="clock" if based_on is None
                                      else _TICKED_BY[self.mode]))
            self._last_drive_ns = self.bus.clock.now_ns()
        except Exception:  # nothing goes out: the motors' watchdog stops the wheels
            self._publish_failed("stop after a failed tick")

    def _run_tick(self, based_on: SourceEntry | None) -> Trace | None:
        # Only what the drive command needs comes before its put; the bookkeeping follows it.
        t0 = time.perf_counter_ns()
        state = self.aggregator.snapshot(previous_action=self.last_action)
        try:
            trace: Trace | None = self.root.evaluate(state)
        except Exception:
            self.stats.errors += 1
            if throttle.first_and_every(self.stats.errors):
                log.exception("behaviour tree raised (error #%d): commanding a stop",
                              self.stats.errors)
            trace = None
        action = trace.action if trace is not None else None
        # float(): an Action takes any real number in range; the trusted drive encoder wants
        # exactly the wire's type.
        speed = float(action.speed) if action is not None and action.speed is not None else 0.0
        turn = float(action.turn) if action is not None and action.turn is not None else 0.0
        basis = based_on if based_on is not None else self.aggregator.newest()
        winners = trace.winning_leaves() if trace is not None else []
        stats = self.stats
        stats.ticks += 1
        command = Drive(
            speed=speed,
            turn=turn,
            based_on=None if basis is None else BasedOn(
                # (ingest refuses a longer name; cut anyway, should one get in, and the
                # test inline: clip() is called only for a name it changes)
                source=basis.source if len(basis.source) <= MAX_NAME_CHARS
                else clip(basis.source, MAX_NAME_CHARS),
                seq=basis.message.seq, stamp_ns=basis.message.stamp_ns),
            tick=stats.ticks,
            winners=tuple(outgoing_names(winners)),
            ticked_by="clock" if based_on is None else _TICKED_BY[self.mode],
        )
        self._last_drive_ns = state.now_ns
        try:
            self._drive.publish(command)
        except Exception:
            self._publish_failed("tick's drive command; a plain stop goes out instead")
            speed = turn = 0.0
            action = None
            command = Drive(speed=0.0, turn=0.0, tick=stats.ticks,
                            ticked_by=command.ticked_by)
            try:
                self._drive.publish(command)
            except Exception:  # nothing goes out: the motors' watchdog stops the wheels
                self._publish_failed("plain stop either")
        if self.bus.clock.resets != self._clock_resets:
            self._clock_resets = self.bus.clock.resets
            stats.new_run()
        stats.tick_starts_ns.append(state.now_ns)
        if based_on is None:
            stats.periodic += 1
            stats.periodic_starts_ns.append(state.now_ns)
            stats.periodic_wall_ns.append(t0)
        counted = stats.winner_ticks
        for w in winners:  # bounded: behaviours of other processes come and go under any name
            if w in counted or len(counted) < MAX_COUNTED_NAMES:
                counted[w] += 1
        if self._tick_hooks:
            run_hooks(self._tick_hooks, "tick", state, trace, command)
        if action is not None and (action.seek_color is not None or action.message is not None
                                   or action.leds is not None):  # (_EXTRA_MESSAGES' fields)
            try:
                self._publish_extras(action)
            except Exception:
                self._publish_failed("tick's seek_color/radio/leds command")
        if trace is not None and self._trace.has_subscribers():
            try:
                self._trace.publish(TickTrace(tick=self.stats.ticks, nodes=trace_nodes(trace)))
            except Exception:
                self._publish_failed("tick's trace")
        last = self.last_action
        if last is None or last.speed != speed or last.turn != turn:  # (else: the same)
            self.last_action = Action(speed=speed, turn=turn)
        self.last_trace = trace
        self.stats.tick_ns.append(time.perf_counter_ns() - t0)
        if not self.ticked.is_set():  # (set, it stays so until a waiter clears it)
            self.bus.call_on_loop(self.ticked.set)  # from the lane: after the command left
        return trace

    def _publish_failed(self, what: str) -> None:
        self.stats.publish_errors += 1
        n = self.stats.publish_errors
        if throttle.first_and_every(n):
            log.exception("could not publish the %s (publish error #%d)", what, n)

    _EXTRA_MESSAGES: ClassVar[dict[str, Callable[[Any], Any]]] = {
        "seek_color": lambda value: SeekColor(lo=tuple(value.lo), hi=tuple(value.hi)),
        "message": lambda value: RadioSend(text=value),
        "leds": lambda value: Leds(mask=value),
    }
    """The command each optional action field becomes."""

    def _publish_extras(self, action: Action) -> None:
        for field_name, publisher in self._extras.items():
            value = getattr(action, field_name)
            if value is None or self._sent.get(field_name) == value:
                continue
            self._sent[field_name] = value
            publisher.publish(self._EXTRA_MESSAGES[field_name](value))

    def status(self) -> dict[str, Any]:
        with self.lock:
            return self._status_now()

    def _status_now(self) -> dict[str, Any]:
        explanation = self.last_trace.render() if self.last_trace is not None else ""
        now_s = time.monotonic()  # the departures' clock
        last = self.last_action
        return {
            "mode": str(self.mode),
            "rate_hz_target": self.rate_hz if self.mode is TickMode.PERIODIC else None,
            **self.stats.summary(),
            "speed": last.speed if last else None,
            "turn": last.turn if last else None,
            "winners": outgoing_names(self.last_trace.winning_leaves())
            if self.last_trace else [],
            "explanation": explanation[:MAX_EXPLANATION_CHARS],
            "quarantined": outgoing_names(self.quarantined()),
            "tree_changes": len(self.tree_changes),
            "refused": self.aggregator.refusals(),
            "dropped": self.aggregator.dropped(),
            "sources": [
                {"source": s.source, "age_s": s.age_s, "stale": s.stale, "schema": s.schema,
                 "refused": sum(s.refused.values()),
                 **({"stale_why": s.stale_why} if s.stale_why else {}),
                 **({"departed": s.departed.how, "departed_why": s.departed.explain(now_s)}
                    if s.departed else {})}
                for s in self.aggregator.sources()[:256]
            ],
            "clock_domain": self.aggregator.clock_domain.status(),
            "clock": "simulated" if self.bus.clock.is_simulated else "monotonic",
            "host": self.host,
        }

    def runs(self, name: str) -> bool:
        """Whether the tree has a behaviour called ``name`` (a scenario's expectation is
        judged only on a robot that runs what it describes)."""
        with self.lock:
            root = self.root
            return (root.find(name) if isinstance(root, Composite) else
                    root if root.name == name else None) is not None

    def tree_changed(self, what: str) -> None:
        """Called by the live tree service when a change was applied: kept, with the robot
        time, for the run's summary (a run is then not the robot file's)."""
        self.tree_changes.append({"at_s": self.bus.clock.now_ns() / 1e9, "what": what})

    def quarantined(self) -> list[str]:
        """Behaviours of the tree quarantined now (``composite/child``); they stay so until
        their composite is reset — the controller's next run, a reload of the tree — or
        they leave and join again."""
        with self.lock:
            return self.root.quarantined() if isinstance(self.root, Composite) else []

    async def _publish_status(self) -> None:
        periods = every(self.status_clock, self.status_period_s)
        await anext(periods)  # now: the first status comes one period after the start
        async for _ in periods:
            try:
                self._status.publish(self.status())
            except Exception:  # the status is best effort: it must not stop the ticks
                self._publish_failed("status")
