"""Replaying a recording onto the bus: ``python -m ubf_async.replay FILE.mcap``.

A recording of :mod:`ubf_async.tools.record` is published back with its **original bytes** and
**original timing**: message ``i`` goes out ``(log_timeᵢ − log_time₀) / K`` wall seconds after
the first at ``--speed K`` (1 by default), or as fast as the bus takes them with ``--fast``.
A simulated run's recording carries the simulator's clock (``ubf/<robot>/clock``), so a fresh
controller that follows it — ``python -m ubf_async.launch ROBOT_FILE --no-sim --sim-time`` —
runs on the recorded simulated time, whatever the pace.

By default only what a controller **takes in** is replayed: sensor samples, remote votes and
the clock (``sensor/**``, ``vote/**``, ``clock``). The commands, traces, heartbeats and status
of the recorded run are what a re-run produces, so they are left out (``--only`` chooses other
keys, relative to ``ubf/<robot>/``). The messages go to the keys of the robot recorded in the
file (its ``ubf_async`` metadata), or of ``--robot`` when given.

The recording's first clock sample goes out first: a simulator sends each instant's clock
after that instant's samples, so a recording that starts mid-run (a recorder attached to a
running robot) would otherwise begin with samples stamped ahead of a follower's clock, which
has no time yet.

A paced replay that falls behind the recorded timing says so on stderr as soon as it is
:data:`WARN_BEHIND_S` behind (and again each time it falls twice as far behind), and in its
last line, with what held it up meanwhile
(:class:`Lag`): waiting for a CPU (a busy machine), reading the file, zenoh's ``put``, its
own computing, or none of those (the process was stopped).

Before the first message goes out the tool waits until the robot is there (it connects to
``tcp/127.0.0.1:7447``, where ``launch`` listens, unless given ``--connect`` or ``--listen``)
**and** something subscribes to what it replays: zenoh delivers a sample only to the
subscribers known when it is put, so a replay into nobody would publish into the void and
report success; and, if the robot has a controller, until it ticks (:func:`wait_for_controller`).
Nobody there after ``--wait-for-robot-s`` is a one-line error (exit status 2).

``--compare`` checks a re-run against the recording: it hears the re-run's drive commands
while it replays, and says how many of the recorded ones were the re-run's command in effect
at their time, a tick's phase allowed (the share identical), where they first differ, and
with ``--compare-plot FILE.png`` draws both (:func:`compare_commands`, :func:`plot_commands`)
— the regression check of a behaviour change on a real recording; ``--fail-under PCT`` makes
a lower share exit 1.

In a program, :class:`Recording` reads and filters a file and :func:`replay` publishes it; given
the re-run's :class:`~ubf_async.clocks.clock.SimClock` and a ``settle`` (the in-process
transport's), :func:`replay` advances the clock to each message's time itself and waits until
everything
delivered has been handled — a deterministic re-run, tick for tick.
"""

from __future__ import annotations

import argparse
import asyncio
import bisect
import contextlib
import logging
import os
import queue
import signal
import sys
import threading
import time
from collections.abc import AsyncGenerator, Awaitable, Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, TYPE_CHECKING

from ubf_async import extras
from ubf_async.cli.args import HelpFormatter, add_connection_arguments, connection_options
from ubf_async.cli.attach import DEFAULT_ATTACH_TIMEOUT_S, wait_for_robot
from ubf_async.cli.run import run_main
from ubf_async.clocks.clock import SimClock
from ubf_async.errors import ConfigurationError, NoRobotError, ProtocolError
from ubf_async.net.keyexpr import intersects
from ubf_async.net.options import DEFAULT_LISTEN
from ubf_async.runtime import controller
from ubf_async.runtime.bus import Bus, RawPublisher
from ubf_async.wire.protocol import decode
from ubf_async.wire.topics import DRIVE

if TYPE_CHECKING:
    from mcap.reader import McapReader
    from mcap.records import Channel

__all__ = ["CLOCK_LOOKAHEAD", "CLOCK_LOOKAHEAD_NS", "COMPARE_WAIT_S", "CONTINUED", "CONTROLLER",
           "CONTROLLER_INPUTS", "PROBE_SCHEMA", "PROG", "SETTLE_S", "WARN_BEHIND_S", "Command",
           "Comparison", "Lag", "Recorded", "Recording", "ReplayStats", "Settle", "ThreadTimes",
           "build_parser", "compare_commands", "drive_command", "main", "plot_commands",
           "recorded_commands", "replay", "wait_for_controller",
           "wait_for_listeners"]

log = logging.getLogger(__name__)

CONTROLLER_INPUTS = ("sensor/**", "vote/**", "clock")
"""What is replayed by default: what a controller takes in (keys under ``ubf/<robot>/``)."""
CLOCK_LOOKAHEAD = 1000
CLOCK_LOOKAHEAD_NS = 100_000_000
"""How far into a recording (messages, recorded time) its first clock sample is looked for,
to be sent first (:meth:`Recording.__iter__`); a simulator sends one every step."""


def _reader(stream: IO[bytes]) -> McapReader:
    from mcap.reader import make_reader  # the record extra, which Recording requires

    return make_reader(stream)


@dataclass(frozen=True, slots=True)
class Recorded:
    key: str
    payload: bytes
    log_time_ns: int


class Recording:
    """The messages of an MCAP recording of ``robot`` (``None``: the file's) whose keys match
    ``only`` (key expressions relative to ``ubf/<robot>/``), in log-time order."""

    def __init__(self, path: Path, *, only: Sequence[str] = CONTROLLER_INPUTS,
                 robot: str | None = None) -> None:
        self.path = path
        # The feature's entry: a missing extra is one line before anything starts.
        extras.require("record", "mcap", who="replaying a recording")
        from mcap.exceptions import McapError

        try:
            with path.open("rb") as f:
                reader = _reader(f)
                metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        except (OSError, ValueError, McapError) as exc:
            raise ConfigurationError(f"{path}: not a readable MCAP recording ({exc})") from None
        recorded = metadata.get("ubf_async", {}).get("robot")
        if recorded is None:
            raise ConfigurationError(f"{path}: not a ubf_async recording (no ubf_async "
                                     f"metadata)")
        self.recorded_robot = recorded
        self.robot = robot or recorded
        self.simulated = metadata["ubf_async"].get("clock") == "simulated"
        self._from = f"ubf/{recorded}/"
        self._patterns = [self._from + o.strip("/") for o in only]
        clock = self._from + "clock"
        self._clock_key = (f"ubf/{self.robot}/clock"
                           if any(intersects(p, clock) for p in self._patterns) else None)

    def _replayed_on(self, channel: Channel) -> str | None:
        """The key a recorded channel's messages are replayed on, or ``None``: not replayed
        (the live view's Foxglove channels are derived; another robot's, or not in
        ``only``)."""
        topic = channel.topic
        if (channel.message_encoding != "msgpack" or not topic.startswith(self._from)
                or not any(intersects(p, topic) for p in self._patterns)):
            return None
        return f"ubf/{self.robot}/{topic[len(self._from):]}"

    def __iter__(self) -> Iterator[Recorded]:
        """The messages in log-time order, except that the first clock sample (when the clock
        is replayed) comes first, at the first message's time: a simulator sends an instant's
        clock after its samples, and a follower that has no time yet would find those samples
        ahead of its clock."""
        messages = self._messages()
        if self._clock_key is None:
            yield from messages
            return
        held: list[Recorded] = []
        for message in messages:
            if message.key == self._clock_key:
                start = held[0].log_time_ns if held else message.log_time_ns
                yield Recorded(message.key, message.payload, start)
                yield from held
                break
            held.append(message)
            if (len(held) >= CLOCK_LOOKAHEAD
                    or message.log_time_ns - held[0].log_time_ns > CLOCK_LOOKAHEAD_NS):
                yield from held  # no clock near the start: nothing to move
                break
        else:
            yield from held
            return
        yield from messages

    def _messages(self) -> Iterator[Recorded]:
        replayed_on: dict[int, str | None] = {}  # by channel id: decided once per channel
        with self.path.open("rb") as f:
            for _, channel, message in _reader(f).iter_messages(log_time_order=True):
                if channel.id not in replayed_on:
                    replayed_on[channel.id] = self._replayed_on(channel)
                key = replayed_on[channel.id]
                if key is not None:
                    yield Recorded(key, message.data, message.log_time)

    def keys(self) -> list[str]:
        """The keys (under ``ubf/<robot>/``) this recording publishes on, sorted. Reads the
        file's summary; a file without one (a killed recorder's) is read through."""
        with self.path.open("rb") as f:
            summary = _reader(f).get_summary()
        if summary is None:
            return sorted({m.key for m in self})
        replayed = (self._replayed_on(c) for c in summary.channels.values())
        return sorted({key for key in replayed if key is not None})

    async def read_ahead(self, *, batch: int = 256, batches: int = 8,
                         times: ThreadTimes | None = None) -> AsyncGenerator[Recorded, None]:
        """:meth:`__iter__` with the file read and decompressed on a thread (never on the
        event loop), at most ``batches`` × ``batch`` messages ahead of the consumer. The
        reading thread notes its times in ``times`` after each batch."""
        ahead: queue.Queue[list[Recorded] | BaseException | None] = queue.Queue(batches)
        stop = threading.Event()

        def put(item: list[Recorded] | BaseException | None) -> bool:
            while not stop.is_set():  # bounded, and called off when the consumer leaves
                try:
                    ahead.put(item, timeout=0.1)
                    return True
                except queue.Full:
                    continue
            return False

        def read() -> None:
            cpu_wait = _CpuWait()  # this thread's

            def note() -> None:
                if times is not None:
                    times.cpu_s, times.cpu_wait_s = time.thread_time(), cpu_wait.seconds()

            try:
                chunk: list[Recorded] = []
                for message in self:
                    if stop.is_set():
                        return
                    chunk.append(message)
                    if len(chunk) == batch:
                        note()
                        if not put(chunk):
                            return
                        chunk = []
                note()
                if chunk and not put(chunk):
                    return
                put(None)
            except BaseException as exc:  # handed over: raised on the loop, in the consumer
                put(exc)
            finally:
                cpu_wait.close()

        reader = threading.Thread(target=read, name=f"replay:{self.path.name}", daemon=True)
        reader.start()
        try:
            while True:
                item = await asyncio.to_thread(ahead.get)
                if item is None:
                    return
                if isinstance(item, BaseException):
                    raise item
                for message in item:
                    yield message
        finally:
            stop.set()
            # Wake a get still waiting in its worker thread (a cancelled replay), so that the
            # loop's executor can shut down; a full queue has nobody waiting on it.
            with contextlib.suppress(queue.Full):
                ahead.put_nowait(None)
            # And see the reader out (it stops at its next message): a thread still inside a
            # decompressor when the interpreter finalizes is killed by a forced unwind, which
            # aborts the process ("FATAL: exception not rethrown") instead of exiting it.
            await asyncio.to_thread(reader.join)


Settle = Callable[[], Awaitable[None]]


@dataclass
class ThreadTimes:
    """A thread's CPU time and its wait for a CPU (:class:`_CpuWait`; ``None`` where not
    measurable), as it last noted them, for another thread to read."""

    cpu_s: float = 0.0
    cpu_wait_s: float | None = 0.0


WARN_BEHIND_S = 0.1
"""How far behind the recorded timing a paced replay falls before it says why (five periods
of a 50 Hz controller that follows the replayed clock: it sees its time jump by as much)."""


class _CpuWait:
    """How long the calling thread has waited for a CPU while ready to run (Linux's
    ``/proc/thread-self/schedstat``, second field); ``None`` where that is not available."""

    def __init__(self) -> None:
        try:
            self._fd: int | None = os.open("/proc/thread-self/schedstat", os.O_RDONLY)
        except (OSError, AttributeError):
            self._fd = None

    def seconds(self) -> float | None:
        if self._fd is None:
            return None
        try:
            return int(os.pread(self._fd, 128, 0).split()[1]) / 1e9
        except (OSError, ValueError, IndexError):
            return None

    def close(self) -> None:
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None


@dataclass(frozen=True, slots=True)
class _Since:
    """Where the replay stood at a moment: its thread's times and the reader's."""

    at_s: float
    cpu_wait_s: float | None
    computing_s: float
    waited_for_reader_s: float
    publishing_s: float
    reader_cpu_s: float
    reader_cpu_wait_s: float | None
    continued: int = 0
    """SIGCONTs this process received (:data:`CONTINUED`): it had been stopped."""

    def __sub__(self, then: _Since) -> _Since:
        def minus(a: float | None, b: float | None) -> float | None:
            return None if a is None or b is None else a - b

        return _Since(self.at_s - then.at_s, minus(self.cpu_wait_s, then.cpu_wait_s),
                      self.computing_s - then.computing_s,
                      self.waited_for_reader_s - then.waited_for_reader_s,
                      self.publishing_s - then.publishing_s,
                      self.reader_cpu_s - then.reader_cpu_s,
                      minus(self.reader_cpu_wait_s, then.reader_cpu_wait_s),
                      self.continued - then.continued)


@dataclass(frozen=True, slots=True)
class Lag:
    """How far a paced replay fell behind, and what held it up since it was last on time
    (``elapsed_s``)."""

    behind_s: float
    at_s: float
    """When, in the recording's time from its first message."""
    elapsed_s: float
    cpu_wait_s: float | None
    """Ready to run but waiting for a CPU, the replay's thread or its reader's while it was
    waited for: the machine is busy (``None``: not measurable here)."""
    computing_s: float
    """The replay's thread on the CPU: its own work."""
    reading_s: float
    """Waiting for the reading thread while it read and decompressed the file."""
    publishing_s: float
    """Inside zenoh's ``put``: the network or the receivers did not take the messages."""
    stopped: bool = False
    """The process was stopped meanwhile (SIGSTOP, Ctrl-Z) and continued: whichever of the
    times above it was stopped in holds the stop too."""

    @classmethod
    def of(cls, behind_s: float, at_s: float, spent: _Since) -> Lag:
        """From what was ``spent`` since the replay was last on time. Waiting for the reader
        counts as reading only while the reader ran, and as waiting for a CPU while it
        waited for one; the rest of that wait is left unexplained (a stopped process)."""
        waited = spent.waited_for_reader_s
        reading = min(waited, max(0.0, spent.reader_cpu_s))
        cpu_wait = spent.cpu_wait_s
        if cpu_wait is not None and spent.reader_cpu_wait_s is not None:
            cpu_wait += min(waited - reading, max(0.0, spent.reader_cpu_wait_s))
            # Both threads may have waited at once: no more than the time left unexplained.
            cpu_wait = min(cpu_wait, max(0.0, spent.at_s - reading - spent.computing_s
                                         - spent.publishing_s))
        return cls(behind_s=behind_s, at_s=at_s, elapsed_s=spent.at_s, cpu_wait_s=cpu_wait,
                   computing_s=spent.computing_s, reading_s=reading,
                   publishing_s=spent.publishing_s, stopped=spent.continued > 0)

    def cause(self) -> str:
        """What held the replay up, largest first, each part that counts (≥ 10 % of the
        time): one clause each."""
        parts: list[tuple[float, str]] = []
        if self.cpu_wait_s is not None:
            cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (
                os.cpu_count() or 1)
            load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
            parts.append((self.cpu_wait_s,
                          f"waited {_ms(self.cpu_wait_s)} for a CPU (the machine is busy: "
                          f"load average {load:.1f} on {cores} "
                          f"{'core' if cores == 1 else 'cores'})"))
        parts.append((self.reading_s, f"waited {_ms(self.reading_s)} for the file to be read and "
                                            f"decompressed"))
        parts.append((self.publishing_s,
                      f"spent {_ms(self.publishing_s)} in zenoh's put (the network or the "
                      f"receivers did not take the messages as fast)"))
        parts.append((self.computing_s, f"computed for {_ms(self.computing_s)}"))
        rest = self.elapsed_s - sum(s for s, _ in parts)
        parts.append((rest, f"neither ran nor waited for a CPU for {_ms(rest)} (it was "
                            f"stopped — Ctrl-Z, a debugger, a suspended machine — or held up "
                            f"by another of its threads)"
                      if self.cpu_wait_s is not None else
                      f"did not run for {_ms(rest)} (a busy machine, or it was stopped)"))
        counted = sorted((p for p in parts if p[0] >= max(0.1 * self.elapsed_s, 0.005)),
                         key=lambda p: -p[0])
        texts = [text for _, text in counted]
        if self.stopped:  # known for sure, whichever measure the stop fell into
            texts.insert(0, "was stopped and continued (SIGSTOP or Ctrl-Z, then SIGCONT): "
                            "it was stopped in what follows")
        if not texts:
            return "nothing measured stands out"
        return "meanwhile this process " + "; it ".join(texts)

    def describe(self) -> str:
        return (f"{_ms(self.behind_s)} behind the recorded timing, {self.at_s:.1f} s into the "
                f"recording: {self.cause()}")


def _ms(seconds: float) -> str:
    return f"{seconds * 1e3:.0f} ms"


@dataclass
class ReplayStats:
    published: int = 0
    late_s: float = 0.0
    """How far behind the recording's timing the replay fell at worst (paced replays)."""
    lag: Lag | None = None
    """What held it up then, when that was at least :data:`WARN_BEHIND_S`."""


async def replay(recording: Recording, *, bus: Bus, speed: float | None = 1.0,
                 clock: SimClock | None = None, settle: Settle | None = None,
                 on_behind: Callable[[Lag], None] | None = None) -> ReplayStats:
    """Publish ``recording`` on ``bus``: paced at ``speed`` × the recorded timing (``None``:
    as fast as possible). With ``clock``, each message is published at its recorded time on
    that clock (advanced here); with ``settle``, each message is handled before the next.
    A paced replay calls ``on_behind`` when it first falls :data:`WARN_BEHIND_S` behind, and
    again each time it falls twice as far behind as when it last did (``stats.lag`` keeps
    the worst)."""
    if speed is not None and not speed > 0:
        raise ConfigurationError(f"speed must be > 0, got {speed}")
    publishers: dict[str, RawPublisher] = {}
    stats = ReplayStats()
    first_ns: int | None = None
    wall_start = 0.0
    cpu_wait = _CpuWait()
    reader = ThreadTimes()
    waited_for_reader_s = publishing_s = 0.0
    monotonic = time.monotonic
    on_time: _Since | None = None
    warn_at_s = WARN_BEHIND_S

    def now_since(at_s: float) -> _Since:
        return _Since(at_s, cpu_wait.seconds(), time.thread_time(), waited_for_reader_s,
                      publishing_s, reader.cpu_s, reader.cpu_wait_s, CONTINUED.count)

    asked_s = monotonic()
    try:
        # Closed here, not when collected: its reading thread is seen out before the
        # process may exit (Recording.read_ahead).
        async with contextlib.aclosing(recording.read_ahead(times=reader)) as messages:
            async for message in messages:
                now = monotonic()
                waited_for_reader_s += now - asked_s
                if first_ns is None:
                    # The schedule starts with the first message in hand, not before the file
                    # was opened: reading the first chunk is not lateness.
                    first_ns, wall_start = message.log_time_ns, now
                    on_time = now_since(now)
                if speed is not None:
                    due = wall_start + (message.log_time_ns - first_ns) / 1e9 / speed
                    delay = due - now
                    if delay > 0:
                        on_time = now_since(due)  # what happens from here on is lateness
                        await asyncio.sleep(delay)
                    elif -delay > stats.late_s:
                        stats.late_s = -delay
                        if -delay >= WARN_BEHIND_S and on_time is not None:
                            stats.lag = Lag.of(-delay, (message.log_time_ns - first_ns) / 1e9,
                                               now_since(now) - on_time)
                            if -delay >= warn_at_s and on_behind is not None:
                                warn_at_s = 2 * -delay  # a few lines however late it gets
                                on_behind(stats.lag)
                if clock is not None and message.log_time_ns > clock.now_ns():
                    clock.advance_to(message.log_time_ns)
                    if settle is not None:
                        await settle()  # what was due by then runs before the message arrives
                publisher = publishers.get(message.key)
                if publisher is None:
                    publisher = publishers[message.key] = bus.raw_publisher(message.key)
                put_s = monotonic()
                publisher.put(message.payload)
                publishing_s += monotonic() - put_s
                stats.published += 1
                if settle is not None:
                    await settle()
                elif speed is None and stats.published % 64 == 0:
                    await asyncio.sleep(0)  # let the loop breathe
                asked_s = monotonic()
    finally:
        cpu_wait.close()
        for publisher in publishers.values():
            publisher.close()
    return stats


class _Continued:
    """SIGCONTs received: a stopped process (Ctrl-Z, SIGSTOP, a debugger) learns it was
    stopped only from the SIGCONT that continues it — a measure of time cannot tell a stop
    from a wait inside a call. :meth:`install` counts them (``python -m ubf_async.replay``
    does; a replay in another program counts none)."""

    def __init__(self) -> None:
        self.count = 0

    def install(self) -> None:
        signal.signal(signal.SIGCONT, self._continued)

    def _continued(self, signum: int, frame: object) -> None:
        self.count += 1


CONTINUED = _Continued()


# -- python -m ubf_async.replay --------------------------------------------------------------

PROG = "python -m ubf_async.replay"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG, formatter_class=HelpFormatter,
        description="Publish an MCAP recording (python -m ubf_async.record, launch --record) "
                    "back onto the bus with its original bytes and timing, so a controller "
                    "or a behaviour can be re-run on recorded inputs (docs/recording.md). A "
                    "simulated run's clock is replayed too: re-run the controller with "
                    "'python -m ubf_async.launch ROBOT_FILE --no-sim --sim-time'.")
    parser.add_argument("file", type=Path, metavar="FILE.mcap")
    add_connection_arguments(parser, default_connect=[DEFAULT_LISTEN],
                             robot_elsewhere="the robot recorded in the file")
    pace = parser.add_mutually_exclusive_group()
    pace.add_argument("--speed", type=float, default=1.0, metavar="K",
                      help="K times the recorded pace")
    pace.add_argument("--fast", action="store_true", help="as fast as possible")
    parser.add_argument("--only", default=",".join(CONTROLLER_INPUTS), metavar="KEYS",
                        help="comma-separated key expressions under ubf/<robot>/ to replay "
                             "(default: what a controller takes in; '**' for everything)")
    parser.add_argument("--wait-for-robot-s", type=float, default=DEFAULT_ATTACH_TIMEOUT_S,
                        metavar="S",
                        help="how long to wait for the robot and for a subscriber of what is "
                             "replayed before giving up (exit status 2)")
    check = parser.add_argument_group("comparing the re-run with the recording")
    check.add_argument("--compare", action="store_true",
                       help="hear the re-run's drive commands and say how they differ from "
                            "the recorded ones: the share identical (the re-run's command in "
                            "effect at each recorded one's time), the first divergence")
    check.add_argument("--compare-plot", type=Path, default=None, metavar="FILE.png",
                       help="with --compare: draw the recorded and the re-run commands")
    check.add_argument("--fail-under", type=float, default=None, metavar="PCT",
                       help="with --compare: exit status 1 when less than PCT %% of the "
                            "recorded commands are identical in the re-run")
    return parser


PROBE_SCHEMA = "replay.probe"
"""The schema named by the publishers :func:`wait_for_listeners` declares to learn who
subscribes (they never publish)."""
SETTLE_S = 1.0
"""Once a key has a subscriber, how long the others get to show theirs (a robot starting up
declares its subscriptions within milliseconds of each other)."""


async def wait_for_listeners(bus: Bus, keys: Sequence[str], *, timeout_s: float,
                             settle_s: float = SETTLE_S, poll_s: float = 0.01) -> list[str]:
    """Wait until something subscribes to ``keys``: return as soon as every key has a
    subscriber, or ``settle_s`` after the first one had (the keys still without one are
    returned). :class:`~ubf_async.errors.NoRobotError` when none has after ``timeout_s``.

    zenoh delivers a sample only to the subscribers its publisher knows when it is put
    (declarations travel asynchronously), so a replay that started before the robot's
    subscriptions had arrived would publish into nothing."""
    probes = [bus.publisher(key, PROBE_SCHEMA) for key in keys]

    def missing() -> list[str]:
        return [p.key for p in probes if not p.has_subscribers()]

    # Polling zenoh's matching status, as Publisher.wait_for_subscribers does.
    try:
        deadline = time.monotonic() + timeout_s
        while (unheard := missing()) and len(unheard) == len(probes):
            if time.monotonic() >= deadline:
                raise NoRobotError(
                    f"nobody subscribes to what this would replay ({len(keys)} keys under "
                    f"ubf/{bus.robot}/: {_some(keys, bus.keys.prefix)}) within "
                    f"{timeout_s:g}s: start the "
                    f"robot to feed first, e.g. `python -m ubf_async.launch ROBOT_FILE "
                    f"--no-sim --sim-time`, and check --connect and --robot")
            await asyncio.sleep(poll_s)
        settled = time.monotonic() + settle_s  # one has a subscriber: the others' chance
        while unheard and time.monotonic() < settled:
            await asyncio.sleep(poll_s)
            unheard = missing()
        return unheard
    finally:
        for probe in probes:
            probe.close()


CONTROLLER = controller.DEFAULT_NAME
"""The component name of the robot's controller (launch's, a fleet's): :func:`wait_for_controller`
waits for it."""


async def wait_for_controller(bus: Bus, *, timeout_s: float) -> bool:
    """Wait until the robot's controller, if it has one, is ticking: its periodic ticks start
    where the clock stands when its loop starts, so a replay whose clock went out before
    that (a controller still starting: its subscriptions are declared before its loop runs)
    would re-run the recording from later on. Its first status says its loop runs: the
    status comes one status period after the loop's task and its own were created, together.
    Returns whether there was a controller to wait for (a robot of devices or behaviours
    alone has none: nothing then to wait for). :class:`~ubf_async.errors.NoRobotError` when
    its controller is alive but sends no status within ``timeout_s``."""
    if not await bus.alive_tokens(bus.keys.alive(CONTROLLER), timeout_s=1.0):
        return False
    ticking = asyncio.Event()
    status = bus.subscribe(bus.keys.status(CONTROLLER),
                           lambda key, payload, received_ns: ticking.set())
    try:
        await asyncio.wait_for(ticking.wait(), timeout_s)
    except TimeoutError:
        raise NoRobotError(f"robot {bus.robot!r}'s {CONTROLLER} is alive but sent no status "
                           f"within {timeout_s:g}s: it is not ticking, and a replay now would "
                           f"lose its start") from None
    finally:
        status.close()
    return True


# -- comparing a re-run with the recording -----------------------------------------------------

Command = tuple[int, float, float, tuple[str, ...]]
"""A drive command as compared: ``(stamp_ns, speed, turn, winners)``."""
COMPARE_WAIT_S = 10.0
"""How long, once the replay is done, ``--compare`` waits for the re-run's command of the
recording's last instant (a busy robot is behind its inputs)."""


def drive_command(payload: bytes) -> Command | None:
    """A drive command's payload as a :data:`Command` (``None``: not a valid one)."""
    try:
        message = decode(payload, schema=DRIVE.schema)
    except ProtocolError:
        return None
    data = message.data
    return (message.stamp_ns, float(data.speed), float(data.turn), tuple(data.winners))


def recorded_commands(path: Path, robot: str | None = None) -> tuple[list[Command], int]:
    """The drive commands of a recording, in log-time order, and the controller's tick
    period (ns: its envelopes' ``period_s``; 20 ms, the default rate's, where they say none).
    """
    commands, period_ns = [], 20_000_000
    for recorded in Recording(path, only=["cmd/drive"], robot=robot):
        command = drive_command(recorded.payload)
        if command is None:
            continue
        commands.append(command)
        period_s = decode(recorded.payload).period_s
        if period_s:
            period_ns = round(period_s * 1e9)
    return commands, period_ns


@dataclass(frozen=True, slots=True)
class Comparison:
    """How a re-run's drive commands compare with the recorded ones."""

    compared: int
    """Recorded commands compared."""
    identical: int
    """Of them, those the re-run also commanded within ``within_ns`` of their time."""
    within_ns: int
    start_ns: int
    """The recording's first command's time: times are said from it."""
    first: tuple[Command, Command | None] | None
    """The first recorded command the re-run did not have in effect, and the re-run's command
    in effect then (``None``: none yet)."""

    @property
    def share(self) -> float:
        return self.identical / self.compared if self.compared else 0.0

    def lines(self) -> list[str]:
        """What ``--compare`` says."""
        said = [f"compared {self.compared} recorded drive commands with the re-run's in "
                f"effect at their time: {self.share:.1%} identical (speed, turn and winners; "
                f"a tick's phase, {self.within_ns / 1e6:g} ms, allowed)"]
        if self.first is not None:
            recorded, rerun = self.first
            at = (recorded[0] - self.start_ns) / 1e9
            said.append(f"  first divergence {at:.2f} s into the recording: recorded "
                        f"{_command_text(recorded)}, the re-run's then "
                        + (_command_text(rerun) if rerun is not None else "none yet"))
        return said


def _command_text(command: Command) -> str:
    _, speed, turn, winners = command
    return f"speed {speed:+.0f} turn {turn:+.0f} ({','.join(winners) or 'stop'})"


def compare_commands(recorded: Sequence[Command], rerun: Sequence[Command], *,
                     within_ns: int) -> Comparison:
    """Each recorded command is identical in the re-run when the re-run's command in effect
    at its time — or one it sent up to ``within_ns`` later (one tick: across processes the
    re-run's ticks need not fall on the recorded instants) — has the same speed, turn and
    winners: what the motors were told, however many ticks either skipped."""
    by_time = sorted(rerun)
    times = [c[0] for c in by_time]
    identical, first = 0, None
    for command in recorded:
        now = bisect.bisect_right(times, command[0])  # the re-run's commands up to its time
        late = bisect.bisect_right(times, command[0] + within_ns)  # ... and a tick later
        in_effect = by_time[now - 1] if now else None
        if any(c[1:] == command[1:] for c in by_time[max(now - 1, 0):late]):
            identical += 1
        elif first is None:
            first = (command, in_effect)
    return Comparison(compared=len(recorded), identical=identical, within_ns=within_ns,
                      start_ns=recorded[0][0] if recorded else 0, first=first)


def plot_commands(path: Path, recorded: Sequence[Command], rerun: Sequence[Command],
                  comparison: Comparison) -> Path:
    """Speed and turn over the recording's time, recorded and re-run, the first divergence
    marked."""
    import matplotlib  # drawn once, at the end

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    start = comparison.start_ns
    figure, axes = plt.subplots(2, 1, figsize=(8, 5), dpi=100, sharex=True)
    for row, (index, name) in enumerate(((1, "speed"), (2, "turn"))):
        ax = axes[row]
        for commands, style, label in ((recorded, "-", "recorded"), (rerun, "--", "re-run")):
            ax.step([(c[0] - start) / 1e9 for c in commands], [c[index] for c in commands],
                    style, where="post", label=label, linewidth=1.2)
        if comparison.first is not None:
            ax.axvline((comparison.first[0][0] - start) / 1e9, color="firebrick",
                       linewidth=0.8, label="first divergence" if row == 0 else None)
        ax.set_ylabel(name)
        ax.grid(alpha=0.3)
    axes[0].legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), ncols=3, fontsize=8,
                   frameon=False)
    axes[1].set_xlabel("s into the recording")
    figure.suptitle(f"{comparison.share:.1%} of {comparison.compared} commands identical",
                    fontsize="medium", x=0.99, ha="right")
    figure.tight_layout()
    figure.savefig(path)
    plt.close(figure)
    return path


async def _main(args: argparse.Namespace) -> int:
    only = [k for k in args.only.split(",") if k.strip()]
    recording = await asyncio.to_thread(Recording, args.file, only=only, robot=args.robot)
    keys = await asyncio.to_thread(recording.keys)
    if not keys:
        raise ConfigurationError(f"{args.file}: nothing to replay: no message of robot "
                                 f"{recording.recorded_robot!r} on {', '.join(only)}")
    args.robot = recording.robot  # --robot, else the file's
    recorded: list[Command] = []
    within = 0
    if args.compare:
        recorded, within = await asyncio.to_thread(recorded_commands, args.file, args.robot)
        if not recorded:
            raise ConfigurationError(f"{args.file}: --compare: the recording has no drive "
                                     f"commands to compare with (record the robot's bus with "
                                     f"launch --record or python -m ubf_async.record)")
    options = connection_options(args)
    bus = await Bus.open(options)
    try:
        rerun: list[Command] = []
        heard_end = asyncio.Event()

        def on_drive(key: str, payload: bytes, received_ns: int) -> None:
            command = drive_command(payload)
            if command is not None:
                rerun.append(command)
                if command[0] >= recorded[-1][0] - within:
                    heard_end.set()

        if args.compare:  # before anything is replayed: every command of the re-run is heard
            bus.subscribe(bus.keys.cmd("drive"), on_drive, latest=False)
        await wait_for_robot(bus, timeout_s=args.wait_for_robot_s)
        unheard = await wait_for_listeners(bus, keys, timeout_s=args.wait_for_robot_s)
        await wait_for_controller(bus, timeout_s=args.wait_for_robot_s)
        print(f"{PROG}: replaying {args.file} onto robot {recording.robot!r} "
              f"({'as fast as possible' if args.fast else f'{args.speed:g}x'}; "
              f"{', '.join(only)}: {len(keys)} keys"
              + (f", {len(unheard)} with no subscriber: {_some(unheard, bus.keys.prefix)}"
                 if unheard else "") + ")", flush=True)
        stats = await replay(recording, bus=bus, speed=None if args.fast else args.speed,
                             on_behind=_warn_behind)
        print(f"{PROG}: {stats.published} messages replayed"
              + (f", at worst {stats.late_s * 1e3:.0f} ms behind" if stats.late_s > 0.01
                 else "")
              + (f", {stats.lag.at_s:.1f} s into the recording: {stats.lag.cause()}"
                 if stats.lag is not None else ""), flush=True)
        if not args.compare:
            return 0
        with contextlib.suppress(TimeoutError):  # what came by then is compared
            await asyncio.wait_for(heard_end.wait(), COMPARE_WAIT_S)
        comparison = compare_commands(recorded, rerun, within_ns=within)
        print("\n".join(f"{PROG}: {line}" if i == 0 else line
                        for i, line in enumerate(comparison.lines())), flush=True)
        if args.compare_plot is not None:
            await asyncio.to_thread(plot_commands, args.compare_plot, recorded, rerun,
                                    comparison)
            print(f"  plot written to {args.compare_plot}", flush=True)
        if args.fail_under is not None and comparison.share * 100 < args.fail_under:
            print(f"{PROG}: {comparison.share:.1%} identical, under --fail-under "
                  f"{args.fail_under:g} %", file=sys.stderr, flush=True)
            return 1
        return 0
    finally:
        await bus.aclose()


def _warn_behind(lag: Lag) -> None:
    print(f"{PROG}: falling behind: {lag.describe()}. Going on: late messages go out at once, "
          f"in order, so a controller following the replayed clock sees its time jump (its "
          f"status counts the ticks it skips as overruns)", file=sys.stderr, flush=True)


def _some(keys: Sequence[str], prefix: str, shown: int = 3) -> str:
    short = [k.removeprefix(prefix + "/") for k in keys[:shown]]
    return ", ".join(short) + (f" and {len(keys) - shown} more" if len(keys) > shown else "")


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not args.fast and not args.speed > 0:
        parser.error(f"--speed must be > 0, got {args.speed:g}")
    if (args.compare_plot is not None or args.fail_under is not None) and not args.compare:
        parser.error("--compare-plot and --fail-under go with --compare")
    logging.basicConfig(level="WARNING", format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    CONTINUED.install()  # a stop (Ctrl-Z) is then named for what it was
    return run_main(lambda: _main(args), prog=PROG)


if __name__ == "__main__":
    raise SystemExit(main())
