"""A robot file's tree fed a script: the real aggregator and controller on the in-process
transport, in simulated time — milliseconds of wall time for seconds of robot time."""

from __future__ import annotations

import asyncio
import dataclasses
import difflib
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from ubf_async.assembly.robotfile import Robot, load_robot
from ubf_async.clocks.clock import SimClock
from ubf_async.core.action import Action
from ubf_async.core.behavior import Behavior, Child, Composite, Trace
from ubf_async.core.state import State
from ubf_async.errors import ConfigurationError
from ubf_async.net.inprocess import InProcessTransport
from ubf_async.runs.wiring import ControllerSettings
from ubf_async.runtime.aggregator import StateAggregator
from ubf_async.runtime.bus import Bus, Publisher
from ubf_async.runtime.controller import Controller
from ubf_async.testing._script import Sample, Script
from ubf_async.wire.protocol import Message
from ubf_async.wire.topics import DRIVE, Drive, sensor_topic

__all__ = ["Command", "ScriptRun", "StandIn", "run_script", "run_script_async", "stand_in"]

S = 1_000_000_000
AROUND_TICKS = 3
"""Ticks before and after a moment that a failure message shows."""


# -- stand-ins ---------------------------------------------------------------------------------


class StandIn(Behavior):
    """A scripted behaviour in place of one of the robot file's: ``act`` is
    ``acts(state)``, or — given a timeline ``[(t_s, action or None), ...]`` — the action of the
    last step at or before the tick's robot time (``None`` before the first: abstain)."""

    def __init__(self, name: str, acts: Callable[[State], Action | None] | None = None, *,
                 timeline: Sequence[tuple[float, Action | None]] = ()) -> None:
        super().__init__(name=name)
        if (acts is None) == (not timeline):
            raise ConfigurationError("a stand-in takes a function or a timeline, one of them")
        self._acts = acts
        self._timeline = sorted(timeline, key=lambda step: step[0])

    def act(self, state: State) -> Action | None:
        if self._acts is not None:
            return self._acts(state)
        now_s = state.now_ns / S
        current: Action | None = None
        for t_s, action in self._timeline:
            if t_s > now_s:
                break
            current = action
        return current


def stand_in(acts: Callable[[State], Action | None] | None = None, *,
             timeline: Sequence[tuple[float, Action | None]] = ()) -> Callable[[str], StandIn]:
    """What :func:`run_script`'s ``substitute`` takes for one behaviour: a function of the
    state, or a timeline of actions. The stand-in takes the replaced behaviour's name, place,
    priority and weight."""
    return lambda name: StandIn(name, acts, timeline=timeline)


def _substitute(root: Composite, substitutes: Mapping[str, Callable[[str], Behavior]]) -> None:
    found: set[str] = set()

    def visit(composite: Composite) -> None:
        children = []
        for child in composite.children:
            make = substitutes.get(child.behavior.name)
            if make is not None:
                found.add(child.behavior.name)
                children.append(Child(make(child.behavior.name), child.priority, child.weight))
            else:
                if isinstance(child.behavior, Composite):
                    visit(child.behavior)
                children.append(child)
        if any(new is not old for new, old in zip(children, composite.children, strict=True)):
            composite.replace_children(children)

    visit(root)
    missing = sorted(set(substitutes) - found)
    if missing:
        names = sorted(_names(root))
        near = difflib.get_close_matches(missing[0], names, n=1)
        raise ConfigurationError(
            f"no behaviour named {missing[0]!r} in the tree to substitute"
            + (f" (did you mean {near[0]!r}?)" if near else "") + f"; it has {', '.join(names)}")


def _names(composite: Composite) -> list[str]:
    out = []
    for child in composite.children:
        out.append(child.behavior.name)
        if isinstance(child.behavior, Composite):
            out += _names(child.behavior)
    return out


# -- what came out -----------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Command:
    """One drive command the controller sent: a tick's, or a hold between ticks."""

    t_s: float
    speed: float
    turn: float
    winners: tuple[str, ...]
    tick: int
    hold: bool
    trace: str | None = field(default=None, compare=False)
    """The tick's trace, rendered (``*`` marks who won; ``None`` for a hold)."""

    def __repr__(self) -> str:
        what = "hold of tick" if self.hold else "tick"
        head = (f"Command(t={self.t_s:.3f} s, {what} {self.tick}, speed={self.speed:+g}, "
                f"turn={self.turn:+g}, winners={self.winners})")
        return head + ("\n" + _indent(self.trace) if self.trace else "")


def _indent(text: str) -> str:
    return "\n".join(f"    {line}" for line in text.splitlines())


class ScriptRun:
    """What a script made the tree do (:func:`run_script`): every drive command, with the
    tick's trace. Its questions answer in robot time; the answers' ``repr`` shows the ticks
    around the moment, so a failing ``assert`` explains itself."""

    def __init__(self, commands: list[Command], until_s: float) -> None:
        self.commands = commands
        self.until_s = until_s

    def drive_at(self, t_s: float) -> Command:
        """The command in effect at ``t_s``: the last one sent at or before it."""
        earlier = [c for c in self.commands if c.t_s <= t_s + 1e-12]
        if not earlier:
            raise AssertionError(f"no drive command at or before {t_s:g} s; the first came at "
                                 f"{self.commands[0].t_s:g} s" if self.commands
                                 else "no drive command at all")
        return earlier[-1]

    def winners_at(self, t_s: float) -> tuple[str, ...]:
        """Who won the drive command in effect at ``t_s``."""
        return self.drive_at(t_s).winners

    def became_active(self, name: str, *, after_s: float = 0.0) -> float:
        """When ``name`` first won a command at or after ``after_s`` (AssertionError, with the
        winners seen, if it never did)."""
        for command in self.commands:
            if command.t_s >= after_s and name in command.winners:
                return command.t_s
        seen = sorted({w for c in self.commands if c.t_s >= after_s for w in c.winners})
        raise AssertionError(f"{name!r} never won a command from {after_s:g} s to "
                             f"{self.until_s:g} s; the winners were {seen or 'nobody'}; the "
                             f"last ticks:\n{self.around(self.until_s)}")

    def held_for(self, name: str, *, from_s: float = 0.0, to_s: float | None = None) -> float:
        """For how long, in robot time between ``from_s`` and ``to_s`` (the run's end), the
        command in effect had ``name`` among its winners."""
        end_s = self.until_s if to_s is None else to_s
        total = 0.0
        for command, after in zip(self.commands, [*self.commands[1:], None], strict=True):
            start = max(command.t_s, from_s)
            stop = min(after.t_s if after is not None else self.until_s, end_s)
            if stop > start and name in command.winners:
                total += stop - start
        return total

    def around(self, t_s: float, *, ticks: int = AROUND_TICKS) -> str:
        """The commands around ``t_s`` with their traces (what a failure message shows)."""
        index = max((i for i, c in enumerate(self.commands) if c.t_s <= t_s), default=0)
        chosen = self.commands[max(0, index - ticks):index + ticks + 1]
        return "\n".join(repr(c) for c in chosen)

    def __repr__(self) -> str:
        return f"<ScriptRun {len(self.commands)} commands in {self.until_s:g} s>"


# -- the run -----------------------------------------------------------------------------------


async def run_script_async(robot: str | Path | Robot, script: Script, *, until_s: float,
                           substitute: Mapping[str, Callable[[str], Behavior]] | None = None,
                           seed: int | None = None) -> ScriptRun:
    """:func:`run_script` on the running event loop."""
    if not (math.isfinite(until_s) and until_s > 0):
        raise ConfigurationError(f"until_s must be > 0, got {until_s!r}")
    resolved = robot if isinstance(robot, Robot) else load_robot(robot, seed=seed)
    if substitute:
        _substitute(resolved.root, substitute)
    settings = ControllerSettings.of(resolved)
    spec = resolved.spec.controller
    net, clock = InProcessTransport(), SimClock(0)
    robot_bus = Bus(transport=net, robot=resolved.name, clock=clock)
    device_bus = Bus(transport=net, robot=resolved.name, clock=clock)
    aggregator = StateAggregator(bus=robot_bus, stale_after_s=spec.stale_after_s,
                                 default_stale_after_s=spec.default_stale_after_s,
                                 fused=spec.fusions())
    controller = Controller(bus=robot_bus, aggregator=aggregator, root=resolved.root,
                            rate_hz=settings.rate_hz, mode=settings.mode,
                            sync_source=settings.sync_source, trigger=settings.trigger,
                            reflex_sources=settings.reflex, lane=False)
    traces: dict[int, str] = {}

    def on_tick(state: State, trace: Trace | None, command: Drive) -> None:
        if trace is not None and command.tick is not None:
            traces[command.tick] = trace.render()

    commands: list[Command] = []

    def on_drive(key: str, message: Message[Drive], received_ns: int) -> None:
        data = message.data
        commands.append(Command(t_s=message.stamp_ns / S, speed=data.speed, turn=data.turn,
                                winners=tuple(data.winners), tick=data.tick or 0,
                                hold=data.hold))

    malformed: dict[str, int] = {}
    listening = device_bus.subscribe_topic(DRIVE.key(device_bus.keys), DRIVE, on_drive,
                                           malformed, latest=False)
    controller.on_tick(on_tick)
    publishers: dict[tuple[str, float | None], Publisher] = {}
    try:
        with clock.driven():  # this is the clock's simulator: its time source is alive
            await aggregator.start()
            await controller.start()
            await net.settle()
            await _play(script.samples, until_s, clock, net, device_bus, publishers)
    finally:
        listening.close()
        for publisher in publishers.values():
            publisher.close()
        await controller.aclose()
        await aggregator.aclose()
        await device_bus.aclose()
        await robot_bus.aclose()
    return ScriptRun([c if c.hold else dataclasses.replace(c, trace=traces.get(c.tick))
                      for c in commands], until_s)


async def _play(samples: list[Sample], until_s: float, clock: SimClock,
                net: InProcessTransport, bus: Bus,
                publishers: dict[tuple[str, float | None], Publisher]) -> None:
    """Advance robot time from event to event — the next sample, the next sleeper's
    deadline — publishing each sample at its time, until ``until_s``."""
    until_ns = round(until_s * S)
    pending = list(samples)
    while True:
        now = clock.now_ns()
        while pending and round(pending[0].t_s * S) <= now:
            _publish(pending.pop(0), bus, publishers)
        await net.settle()
        if now >= until_ns:
            return
        due = [until_ns]
        if pending:
            due.append(round(pending[0].t_s * S))
        wakeup = clock.next_wakeup_ns()
        if wakeup is not None:
            due.append(wakeup)
        clock.advance_to(max(now + 1, min(due)))


def _publish(sample: Sample, bus: Bus,
             publishers: dict[tuple[str, float | None], Publisher]) -> None:
    kind, _, name = sample.source.partition("/")
    key = (sample.source, sample.period_s)
    publisher = publishers.get(key)
    if publisher is None:
        topic = sensor_topic(sample.source)
        sensor_key = bus.keys.sensor(kind, name)
        publisher = publishers[key] = (
            bus.publisher(topic, name, period_s=sample.period_s) if topic is not None
            else bus.publisher(sensor_key, kind, period_s=sample.period_s))
    publisher.publish(sample.data)


def run_script(robot: str | Path | Robot, script: Script, *, until_s: float,
               substitute: Mapping[str, Callable[[str], Behavior]] | None = None,
               seed: int | None = None) -> ScriptRun:
    """Feed ``script`` to the tree of ``robot`` (a robot file's path, a shipped name, or a
    loaded :class:`~ubf_async.assembly.robotfile.Robot`) on the real state aggregator and
    controller — its ``controller:`` settings, its mode and rates — over the in-process
    transport, in simulated time from 0 to ``until_s``; every drive command comes back with
    its tick's trace. ``substitute``: behaviours of the file replaced by stand-ins
    (:func:`stand_in`), by name, without editing the file. Starts its own event loop (in a
    test on one already, ``await`` :func:`run_script_async`)."""
    return asyncio.run(run_script_async(robot, script, until_s=until_s, substitute=substitute,
                                        seed=seed))

