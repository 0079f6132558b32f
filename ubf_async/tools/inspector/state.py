"""``state``: the controller's view — tick rate, drive command, sources with their ages, the last
tick's explanation — and ``--watch``, the refresh in place that ``tree show`` uses too."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import time
from collections.abc import Awaitable, Callable
from typing import Any, TextIO

from ubf_async.clocks import clockdomain
from ubf_async.errors import ProtocolError
from ubf_async.runtime.bus import Bus
from ubf_async.services.status import tick_rates
from ubf_async.tools.inspector import common
from ubf_async.wire import topics
from ubf_async.wire.protocol import Message, decode

__all__ = ["add_state_parser", "add_watch_arguments", "cmd_state", "format_clock_domain",
           "format_state", "watch"]


def add_state_parser(sub: Any, connection: argparse.ArgumentParser) -> None:
    """``state``: the controller's state and the last tick's explanation."""
    state = sub.add_parser(
        "state", parents=[connection], help="the controller's state and last tick's explanation",
        description="Wait for the controller's status (ubf/<robot>/status/<controller>) and "
                    "print its tick rate, drive command, sources with ages, and the last "
                    "tick's explanation: every behaviour's vote, '*' marking the winners.",
    )
    state.add_argument("--controller", default="controller", metavar="NAME",
                       help="the controller component's name (default: controller)")
    state.add_argument("--json", action="store_true", help="print the status as JSON")
    add_watch_arguments(state)


def add_watch_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--watch", "-w", action="store_true",
                        help="refresh in place (one block per refresh when not a terminal)")
    parser.add_argument("--interval", type=float, default=1.0, metavar="S",
                        help="with --watch: seconds between refreshes (default: 1)")
    parser.add_argument("--count", "-n", type=int, default=0, metavar="N",
                        help="with --watch: stop after N refreshes (default: until Ctrl-C)")


def _standing(source: dict[str, Any]) -> str:
    """What a source's line says after its schema: why it is quiet, if it is."""
    if source.get("departed"):
        return f"  {str(source['departed']).upper()}: {source.get('departed_why', '')}"
    if not source.get("stale"):
        return ""
    why = source.get("stale_why")
    return f"  STALE: quiet {why}" if why else "  STALE"


def format_state(status: dict[str, Any], *, robot: str, controller: str,
                 status_age_s: float | None) -> str:
    def num(value: Any, fmt: str, default: str = "--") -> str:
        return format(value, fmt) if isinstance(value, int | float) else default

    lines = []
    age = f", status {status_age_s * 1e3:.0f} ms old" if status_age_s is not None else ""
    mode = str(status.get("mode", "?"))
    # The status line's labels: the clock's ticks apart from the reflex ticks (periodic), or
    # one tick per sample (sync, event).
    rates = tick_rates(mode, common.number(status.get("rate_hz")),
                       common.number(status.get("periodic_rate_hz")))
    target = common.number(status.get("rate_hz_target"))
    if target is not None:
        rates += f" (clock target {target:g}Hz)"
    lines.append(f"robot {robot!r}, {controller}: {mode} mode, {rates}, "
                 f"{status.get('ticks', '?')} ticks, {status.get('overruns', '?')} overruns, "
                 f"{status.get('errors', '?')} errors, "
                 f"tick p50 {num(status.get('tick_us_p50'), '.0f')} us{age}")
    winners = ", ".join(status.get("winners") or []) or "nobody (stop)"
    lines.append(f"drive: speed {num(status.get('speed'), '+.0f')} "
                 f"turn {num(status.get('turn'), '+.0f')}  won by: {winners}")
    sources = status.get("sources") or []
    lines.append(f"sources ({len(sources)}):")
    if not sources:
        lines.append("  (none yet)")
    width = max((len(str(s.get("source", ""))) for s in sources), default=0)
    for s in sources:
        stale = _standing(s)
        age_s = s.get("age_s")
        age_ms = age_s * 1e3 if isinstance(age_s, int | float) else None
        refused = s.get("refused")
        refused_text = f"  refused {refused}" if refused else ""
        lines.append(f"  {s.get('source', '?')!s:{width}}  age {num(age_ms, '7.0f'):>7} ms"
                     f"  {s.get('schema', '')}{stale}{refused_text}")
    refusals = {k: v for k, v in (status.get("refused") or {}).items() if v}
    if refusals:
        lines.append("refused: " + ", ".join(f"{k} {v}" for k, v in refusals.items()))
    dropped = {k: v for k, v in (status.get("dropped") or {}).items() if v}
    if dropped:  # housekeeping, not refusals
        lines.append("sources dropped: " + ", ".join(
            f"{k} {v}" + {"forgotten": " (silent too long)",
                          "evicted": " (to make room: table full)"}.get(k, "")
            for k, v in dropped.items()))
    lines.extend(format_clock_domain(status.get("clock_domain")))
    quarantined = status.get("quarantined") or []
    if quarantined:
        lines.append("quarantined (failing tick after tick, cut off): " + ", ".join(quarantined))
    explanation = status.get("explanation") or "(no tick yet)"
    lines.append("last tick ('*' = won; [p=priority w=weight] <arbiter>):")
    lines.extend(f"  {line}" for line in str(explanation).splitlines())
    return "\n".join(lines)


def format_clock_domain(foreign: Any) -> list[str]:
    """The status's ``clock_domain`` (:mod:`ubf_async.clocks.clockdomain`): sources whose stamps
    are on another clock than the robot's, so their ages mean nothing."""
    if not isinstance(foreign, list) or not foreign:
        return []
    lines = ["stamped on another clock (ages meaningless; see docs/protocol.md "
             "'The robot clock'):"]
    for f in foreign:
        if isinstance(f, dict):
            offset = f.get("offset_s")
            off = f"{offset:+.3g} s" if isinstance(offset, int | float) else "?"
            sender = f", from {f['sender']}" if f.get("sender") else ""
            lines.append(f"  {f.get('source', '?')}  {f.get('samples', '?')} samples, "
                         f"like {clockdomain.the(str(f.get('clock', '?')))}, last {off} off"
                         f"{sender}")
    return lines


async def cmd_state(bus: Bus, args: argparse.Namespace, out: TextIO) -> int:
    keys = bus.keys
    key = topics.CONTROLLER_STATUS.key(keys, args.controller)
    latest: list[Message] = []
    errors: list[str] = []
    arrived = asyncio.Event()

    def on_sample(k: str, payload: bytes, received_ns: int) -> None:
        try:
            latest.append(decode(payload))
        except ProtocolError as exc:
            errors.append(str(exc))
            return
        del latest[:-1]
        arrived.set()

    sim_now: list[int] = []

    def on_clock(clock_key: str, payload: bytes, received_ns: int) -> None:
        with contextlib.suppress(ProtocolError):
            sim_now.append(decode(payload, topic=topics.CLOCK).stamp_ns)
            del sim_now[:-1]

    bus.subscribe(topics.CLOCK.key(bus.keys), on_clock)
    bus.subscribe(key, on_sample)

    async def block() -> str | None:
        try:
            await asyncio.wait_for(arrived.wait(), args.timeout)
        except TimeoutError:
            why = f" (malformed: {errors[-1]})" if errors else ""
            common.say_error(f"no status on {key} within {args.timeout:g}s{why}: is the "
                             f"robot's controller running (--controller, --robot)?")
            return None
        arrived.clear()
        message = latest[-1]
        if args.json:
            return common.to_json({"key": key, "stamp_ns": message.stamp_ns,
                                   "status": message.data})
        # The status is stamped on the robot clock: simulation time when a simulator publishes
        # one (then compare with the newest simulation time seen), else CLOCK_MONOTONIC.
        now_ns = max(sim_now) if sim_now else time.monotonic_ns()
        age = (now_ns - message.stamp_ns) / 1e9
        return format_state(message.data, robot=bus.robot, controller=args.controller,
                            status_age_s=age if 0 <= age < 3600 else None)

    return await watch(block, args, out)


async def watch(block: Callable[[], Awaitable[str | None]], args: argparse.Namespace,
                out: TextIO) -> int:
    """Print ``block()`` once, or with ``--watch`` every ``--interval`` (``--count`` times):
    redrawn in place on a terminal, one block after another otherwise. Exit status 1 when a
    block could not be had."""
    refreshes = 0
    interactive = out.isatty()
    while True:
        text = await block()
        if text is None:
            return 1
        if args.watch and interactive:
            out.write("\x1b[H\x1b[2J")  # the top of a cleared screen
        elif args.watch and refreshes:
            out.write("\n")
        stamp = f"# {time.strftime('%H:%M:%S')} (every {args.interval:g}s)\n" if args.watch else ""
        out.write(stamp + text + "\n")
        out.flush()
        refreshes += 1
        if not args.watch or (args.count and refreshes >= args.count):
            return 0
        await asyncio.sleep(args.interval)
