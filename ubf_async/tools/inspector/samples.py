"""``echo``, ``hz`` and ``bw``: the samples on a key — each decoded and validated like the robot
does, or their rate and bandwidth over a window of messages (per kind of tick for drive
commands)."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import difflib
import itertools
import statistics
import sys
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any, TextIO

import msgpack

from ubf_async.errors import ProtocolError
from ubf_async.runtime.bus import Bus
from ubf_async.runtime.component import HealthMonitor
from ubf_async.tools.inspector import common
from ubf_async.wire import topics
from ubf_async.wire.keys import Keys
from ubf_async.wire.protocol import MAX_PAYLOAD_BYTES, decode

__all__ = ["ECHO_QUIET_S", "ECHO_WAIT_S", "MAX_TICK_KINDS", "MIXED_TICKS", "KeyWindow",
           "add_echo_parser", "add_rate_parsers", "cmd_echo", "cmd_rate", "format_sample",
           "tick_kind", "unpublished"]

MAX_TICK_KINDS = 16
"""Kinds of tick ``hz`` keeps apart per key (a reflex or trigger source each makes one)."""
ECHO_QUIET_S = 2.0
"""How long ``echo`` hears nothing before it says whether anything publishes the key: four
heartbeats of every component, which announce what each publishes."""
ECHO_WAIT_S = 30.0
"""How long ``echo`` waits for a first sample before it gives up (``--wait``): a key whose
publisher has stopped would otherwise keep a ``--count N`` script waiting for ever."""


def add_echo_parser(sub: Any, connection: argparse.ArgumentParser) -> None:
    """``echo``: the samples of a key, decoded."""
    echo = sub.add_parser(
        "echo", parents=[connection], help="print the samples of a key, decoded",
        description="Print every sample on KEY, decoded from msgpack and validated like the "
                    "robot does. Malformed payloads are printed as errors and echo goes on.",
    )
    echo.add_argument("key", metavar="KEY",
                      help="a key or key expression, relative to ubf/<robot>/ unless it "
                           "starts with ubf/ (e.g. sensor/range/front, 'sensor/**')")
    echo.add_argument("--count", "-n", type=int, default=0, metavar="N",
                      help="stop after N samples (default: 0 = until Ctrl-C)")
    echo.add_argument("--seconds", type=float, default=None, metavar="S",
                      help="stop after S seconds")
    echo.add_argument("--wait", type=float, default=ECHO_WAIT_S, metavar="S",
                      help=f"give up (exit status 1) when no sample has come S seconds after "
                           f"the start (default: {ECHO_WAIT_S:g}; 0 waits for ever)")
    echo.add_argument("--raw", action="store_true",
                      help="print the msgpack map as it came, without validation")
    echo.add_argument("--json", action="store_true", help="one JSON object per line")


def format_sample(keys: Keys, key: str, payload: bytes, *, raw: bool, as_json: bool) -> str:
    """One line for one sample: decoded (or raw) fields, or the reason it was rejected."""
    if raw:
        try:
            if len(payload) > MAX_PAYLOAD_BYTES:
                raise ValueError(f"{len(payload)} bytes exceeds {MAX_PAYLOAD_BYTES}")
            value = msgpack.unpackb(payload, raw=False, strict_map_key=False)
        except Exception as exc:  # any unpacker failure is the payload's, not ours
            error = f"not msgpack: {exc}"
            if as_json:
                return common.to_json({"key": key, "error": error})
            return f"{key} ERROR {error}"
        if as_json:
            return common.to_json({"key": key, "raw": value})
        return f"{key} RAW {common.to_json(value)}"
    try:
        message = common.decode_for(keys, key, payload)
    except ProtocolError as exc:
        return common.to_json({"key": key, "error": str(exc)}) if as_json else f"{key} ERROR {exc}"
    if as_json:
        return common.to_json({"key": key, "schema": message.schema, "seq": message.seq,
                      "stamp_ns": message.stamp_ns, "period_s": message.period_s,
                      "data": message.data})
    period = f" period {message.period_s:g}s" if message.period_s is not None else ""
    return (f"{key} {message.schema} #{message.seq} stamp {message.stamp_ns}{period}: "
            f"{common.to_json(message.data)}")


async def cmd_echo(bus: Bus, args: argparse.Namespace, out: TextIO) -> int:
    keys = bus.keys
    if args.wait < 0:
        common.say_error("--wait must be ≥ 0 (0 waits for ever)")
        return 2
    key_expr = common.key_or_report(keys, args.key)
    if key_expr is None:
        return 2
    done = asyncio.Event()
    shown = 0

    def on_sample(key: str, payload: bytes, received_ns: int) -> None:
        nonlocal shown
        if done.is_set():
            return
        print(format_sample(keys, key, payload, raw=args.raw, as_json=args.json), file=out)
        out.flush()
        shown += 1
        if args.count and shown >= args.count:
            done.set()

    monitor = HealthMonitor(bus)  # what the components announce they publish
    monitor.start()
    bus.subscribe(key_expr, on_sample, latest=False)
    if not args.json:
        print(f"# echo {key_expr}", file=out)
        out.flush()

    async def say_if_unpublished() -> None:
        await asyncio.sleep(ECHO_QUIET_S)
        if shown == 0:
            await monitor.heard_from_all(common.HEARD_WITHIN_S)
            if shown == 0:
                print(await unpublished(bus, monitor, key_expr, wait_s=args.wait),
                      file=sys.stderr, flush=True)

    async def give_up_if_none() -> None:
        await asyncio.sleep(args.wait)
        if shown == 0:
            gave_up.set()
            done.set()

    started = asyncio.get_running_loop().time()
    gave_up = asyncio.Event()
    note = asyncio.create_task(say_if_unpublished())
    bound = asyncio.create_task(give_up_if_none()) if args.wait > 0 else None
    try:
        with contextlib.suppress(TimeoutError):  # --seconds elapsed
            await asyncio.wait_for(done.wait(), args.seconds)
        if (not note.done() and shown == 0
                and asyncio.get_running_loop().time() - started >= ECHO_QUIET_S):
            # --seconds or --wait ended while the note waited for heartbeats: say what is
            # known.
            note.cancel()
            print(await unpublished(bus, monitor, key_expr, wait_s=args.wait),
                  file=sys.stderr, flush=True)
        if gave_up.is_set():
            print(f"# nothing came on {key_expr} in {args.wait:g} s: giving up (--wait S "
                  f"waits longer, --wait 0 for ever)", file=sys.stderr, flush=True)
    finally:
        note.cancel()
        if bound is not None:
            bound.cancel()
        monitor.close()
    return 0 if (not args.count or shown >= args.count) and not gave_up.is_set() else 1


async def unpublished(bus: Bus, monitor: HealthMonitor, key_expr: str, *,
                      wait_s: float = ECHO_WAIT_S) -> str:
    """What ``echo`` says on stderr when nothing has arrived on ``key_expr``: whether a live
    component announces publishing it (heartbeats, docs/protocol.md), and the keys they do
    announce that look like it. It goes on waiting, up to ``wait_s`` from its start (0: for
    ever), which the line says."""
    waiting = (f"still waiting (up to {wait_s:g} s from the start; --wait 0 waits for ever)"
               if wait_s > 0 else "still waiting (Ctrl-C stops)")
    tokens = await bus.alive_tokens(bus.keys.all_alive, timeout_s=1.0)
    alive = {bus.keys.component_of_alive(t) for t in tokens} | set(monitor.alive_names())
    publishers = common.announcing(monitor, key_expr, alive)
    if publishers:
        return (f"# nothing on {key_expr} yet, though {', '.join(sorted(publishers))} "
                f"announce{'s' if len(publishers) == 1 else ''} publishing it (it may publish "
                f"only on a change); {waiting}")
    announced = sorted({p.key for c, h in monitor.components.items() if c in alive
                        for p in h.publishes})
    prefix = bus.keys.prefix + "/"
    near = difflib.get_close_matches(key_expr.removeprefix(prefix),
                                     [k.removeprefix(prefix) for k in announced], n=3)
    silent = len(alive - {c for c, h in monitor.components.items() if h.publishes})
    return (f"# nothing publishes {key_expr} yet: none of the {len(alive)} live components "
            f"announces it"
            + (f" ({silent} announce nothing: they publish nothing, or do not say so)"
               if silent else "")
            + (f"; announced keys like it: {', '.join(near)}" if near else "")
            + f"; {waiting} (`inspector keys` lists what is published)")


def add_rate_parsers(sub: Any, connection: argparse.ArgumentParser) -> None:
    """``hz`` and ``bw``: the rate and bandwidth of a key's messages."""
    for name, what in (("hz", "the rate of a key's messages (like ros2 topic hz)"),
                       ("bw", "the bandwidth of a key's messages (like ros2 topic bw)")):
        verb = sub.add_parser(
            name, parents=[connection], help=what,
            description=f"Print {what}, once a second, one line per key: over the last "
                        f"--window messages of each key.")
        verb.add_argument("key", metavar="KEY", help=common.KEY_HELP)
        verb.add_argument("--window", type=int, default=100, metavar="N",
                          help="messages each figure is computed over (default: 100)")
        verb.add_argument("--count", "-n", type=int, default=0, metavar="N",
                          help="stop after N reports (default: until Ctrl-C)")
        verb.add_argument("--seconds", type=float, default=None, metavar="S",
                          help="stop after S seconds")


@dataclass
class KeyWindow:
    """The last ``window`` messages of one key: arrival times (wall) and sizes."""

    window: int
    times_ns: deque[int] = field(init=False)
    sizes: deque[int] = field(init=False)
    count: int = 0
    publishers: set[int] = field(default_factory=set)

    def __post_init__(self) -> None:
        self.times_ns = deque(maxlen=self.window + 1)
        self.sizes = deque(maxlen=self.window)

    def add(self, received_ns: int, payload: bytes) -> None:
        self.count += 1
        self.times_ns.append(received_ns)
        self.sizes.append(len(payload))

    def hz_line(self) -> str:
        gaps = [(b - a) / 1e9 for a, b in itertools.pairwise(self.times_ns)]
        if not gaps:
            return "1 message, no rate yet"
        mean = statistics.fmean(gaps)
        std = statistics.pstdev(gaps)
        return (f"average rate {1 / mean if mean > 0 else float('inf'):.2f} Hz  "
                f"min {min(gaps):.4f}s max {max(gaps):.4f}s std dev {std:.5f}s "
                f"window {len(gaps)}")

    def bw_line(self) -> str:
        span_s = (self.times_ns[-1] - self.times_ns[0]) / 1e9 if len(self.times_ns) > 1 else 0.0
        total = sum(list(self.sizes)[-(len(self.times_ns) - 1):]) if span_s else 0
        rate = f"{total / span_s:.0f} B/s" if span_s else "-- B/s"
        return (f"{rate}  mean {statistics.fmean(self.sizes):.0f} B min {min(self.sizes)} B "
                f"max {max(self.sizes)} B window {len(self.sizes)}")


def tick_kind(payload: bytes) -> str | None:
    """What ran the tick a drive command comes from, labelled as the status line labels tick
    rates — ``clock``, ``reflex (range/front)``, ``sync (camera/front)``, ``event (…)`` — or
    ``hold`` (a triggered controller's repeat); ``None`` for anything but a drive command that
    says (``ticked_by``, docs/protocol.md)."""
    try:
        data = decode(payload, schema=topics.DRIVE.schema).data
    except ProtocolError:
        return None
    if data.hold:
        return "hold"
    if data.ticked_by is None:
        return None
    if data.ticked_by != "clock" and data.based_on is not None:
        return f"{data.ticked_by} ({data.based_on.source})"
    return str(data.ticked_by)


MIXED_TICKS = ("# every tick sends a drive command: the clock's periodic ticks and those a "
               "sample runs at once (a reflex, a sync or event trigger), so two can come "
               "~0 s apart and the rate is their sum; per kind below, as `inspector state` "
               "and launch's status line count them")


async def cmd_rate(bus: Bus, args: argparse.Namespace, out: TextIO) -> int:
    """``hz`` and ``bw``: one line per key, once a second; for ``hz`` of drive commands, one
    more per kind of tick (:func:`tick_kind`)."""
    key_expr = common.key_or_report(bus.keys, args.key)
    if key_expr is None:
        return 2
    if args.window < 2:
        common.say_error("--window must be at least 2")
        return 2
    seen: dict[str, KeyWindow] = {}
    by_kind: dict[str, dict[str, KeyWindow]] = {}
    hz = args.command == "hz"

    def on_sample(key: str, payload: bytes, received_ns: int) -> None:
        window = seen.get(key)
        if window is None:
            window = seen[key] = KeyWindow(args.window)
        window.add(received_ns, payload)
        if hz and (kind := tick_kind(payload)) is not None:
            kinds = by_kind.setdefault(key, {})
            if kind in kinds or len(kinds) < MAX_TICK_KINDS:
                kinds.setdefault(kind, KeyWindow(args.window)).add(received_ns, payload)

    bus.subscribe(key_expr, on_sample, latest=False, max_queue=1 << 16)
    line = KeyWindow.hz_line if hz else KeyWindow.bw_line
    reports = 0
    explained = False
    deadline = None if args.seconds is None else time.monotonic() + args.seconds
    while not args.count or reports < args.count:
        await asyncio.sleep(1.0)
        if deadline is not None and time.monotonic() > deadline:
            break
        if not seen:
            print(f"# no messages on {key_expr} yet", file=out)
        if not explained and any(len(kinds) > 1 for kinds in by_kind.values()):
            print(MIXED_TICKS, file=out)
            explained = True
        for key in sorted(seen):
            print(f"{key}: {line(seen[key])}", file=out)
            for kind, window in sorted(by_kind.get(key, {}).items()):
                print(f"  ticked by {kind}: {line(window)}", file=out)
        out.flush()
        reports += 1
    return 0 if seen else 1
