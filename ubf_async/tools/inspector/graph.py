"""``robots``, ``components``, ``keys`` and ``info``: what is alive on the network and what it
publishes — robots and their controllers, a robot's live components (liveliness tokens and
heartbeats), the keys carrying samples, and what one key carries and who publishes it."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import dataclasses
import time
from dataclasses import dataclass, field
from typing import Any, TextIO

from ubf_async.errors import ProtocolError
from ubf_async.net.keyexpr import intersects
from ubf_async.runtime.bus import Bus
from ubf_async.runtime.component import HealthMonitor
from ubf_async.tools.inspector import common, samples
from ubf_async.wire import reference, topics
from ubf_async.wire.keys import ROOT, Keys
from ubf_async.wire.protocol import decode

__all__ = ["KeyStats", "RobotRow", "add_components_parser", "add_info_parser", "add_keys_parser",
           "add_robots_parser", "cmd_components", "cmd_info", "cmd_keys", "cmd_robots",
           "format_publishers", "print_declared"]


def add_robots_parser(sub: Any, connection: argparse.ArgumentParser) -> None:
    """``robots``: the robots alive on the network this joins."""
    robots = sub.add_parser(
        "robots", parents=[connection], help="list the live robots on a router (a fleet)",
        description="List every robot alive on the zenoh network this joins (a fleet's "
                    "router, docs/fleet.md), whatever --robot says: its live components "
                    "(liveliness tokens ubf/*/alive/*) and, from its controller's status "
                    "heard over --seconds, the tick rate (all ticks, and those of the "
                    "periodic clock), mode and who wins the drive command now.")
    robots.add_argument("--seconds", type=float, default=1.2, metavar="S",
                        help="how long to listen for the controllers' status (published "
                             "every 0.5 s)")
    robots.add_argument("--json", action="store_true", help="print the list as JSON")


@dataclass
class RobotRow:
    robot: str
    components: int = 0
    mode: str | None = None
    tick_hz: float | None = None
    periodic_hz: float | None = None
    winners: list[str] = field(default_factory=list)


async def cmd_robots(bus: Bus, args: argparse.Namespace, out: TextIO) -> int:
    rows: dict[str, RobotRow] = {}

    def on_status(key: str, payload: bytes, received_ns: int) -> None:
        try:
            message = decode(payload, topic=topics.CONTROLLER_STATUS)
        except ProtocolError:
            return  # another component's status, or malformed: not a controller's
        status = message.data
        row = rows.setdefault(key.split("/")[1], RobotRow(robot=key.split("/")[1]))
        row.mode = str(status.get("mode")) if status.get("mode") is not None else None
        row.tick_hz = common.number(status.get("rate_hz"))
        row.periodic_hz = common.number(status.get("periodic_rate_hz"))
        row.winners = [str(w) for w in status.get("winners") or []]

    subscription = bus.subscribe(f"{ROOT}/*/status/*", on_status,
                                 latest=False)
    await asyncio.sleep(args.seconds)  # a listening window: the statuses heard in it
    subscription.close()
    for token in await bus.alive_tokens(f"{ROOT}/*/alive/*", timeout_s=args.timeout):
        robot = token.split("/")[1]
        rows.setdefault(robot, RobotRow(robot=robot)).components += 1
    listed = sorted(rows.values(), key=lambda row: row.robot)
    if args.json:
        print(common.to_json({"robots": [dataclasses.asdict(row) for row in listed]}), file=out)
        return 0
    if not listed:
        print("no robot alive", file=out)
        return 0
    width = max(5, *(len(row.robot) for row in listed))
    print(f"{'ROBOT':{width}}  COMPONENTS  PERIODIC Hz  ALL TICKS Hz  MODE      WINNING", file=out)
    for row in listed:
        def hz(value: float | None) -> str:
            return f"{value:.1f}" if value is not None else "--"

        print(f"{row.robot:{width}}  {row.components:>10}  {hz(row.periodic_hz):>11}  "
              f"{hz(row.tick_hz):>12}  {row.mode or '--':8}  "
              f"{', '.join(row.winners) or ('(stop)' if row.mode else '--')}", file=out)
    return 0


def add_components_parser(sub: Any, connection: argparse.ArgumentParser) -> None:
    """``components``: the robot's live components."""
    components = sub.add_parser(
        "components", parents=[connection], help="list the live components (liveliness tokens)",
        description="List the robot's live components: one name per line, sorted, from the "
                    "liveliness tokens ubf/<robot>/alive/*. Exactly those whose token is "
                    "present now; a killed process disappears as soon as its session ends.",
    )
    components.add_argument("--long", "-L", action="store_true",
                            help="also listen to heartbeats for --heartbeat-s and show health")
    components.add_argument("--heartbeat-s", type=float, default=1.2, metavar="S",
                            help="with --long: how long to listen for heartbeats")


async def cmd_components(bus: Bus, args: argparse.Namespace, out: TextIO) -> int:
    keys = bus.keys
    monitor: HealthMonitor | None = None
    if args.long:
        monitor = HealthMonitor(bus)
        monitor.start()
        await asyncio.sleep(args.heartbeat_s)
    tokens = await bus.alive_tokens(keys.all_alive, timeout_s=args.timeout)
    names = sorted({keys.component_of_alive(t) for t in tokens})
    if monitor is None:
        for name in names:
            print(name, file=out)
        return 0
    now = time.monotonic()
    for name in names:
        health = monitor.components.get(name)
        if health is None or health.last_heartbeat_s is None:
            detail = "token only: no heartbeat (none sent, or none yet), judged by its token"
        else:
            state = "healthy" if health.healthy(now) else "UNHEALTHY"
            detail = (f"{state}: heartbeat {now - health.last_heartbeat_s:.2f}s ago, "
                      f"restarts {health.restarts}, loop lag {health.loop_lag_s * 1e3:.1f}ms")
        print(f"{name:24} {detail}", file=out)
    monitor.close()
    return 0


def add_keys_parser(sub: Any, connection: argparse.ArgumentParser) -> None:
    """``keys``: the keys carrying samples."""
    keys = sub.add_parser(
        "keys", parents=[connection], help="list the keys carrying samples, with rates",
        description="Listen to ubf/<robot>/** for --seconds and list every key that carried "
                    "samples: count, rate, schema of the last sample, malformed payloads.",
    )
    keys.add_argument("--seconds", type=float, default=2.0, metavar="S",
                      help="how long to listen (default: 2)")


@dataclass
class KeyStats:
    count: int = 0
    malformed: int = 0
    schema: str = "?"
    bytes: int = 0
    first_ns: int = 0
    last_ns: int = 0
    error: str = ""


async def cmd_keys(bus: Bus, args: argparse.Namespace, out: TextIO) -> int:
    keys = bus.keys
    seen: dict[str, KeyStats] = {}

    def on_sample(key: str, payload: bytes, received_ns: int) -> None:
        stats = seen.get(key)
        if stats is None:
            stats = seen[key] = KeyStats(first_ns=received_ns)
        stats.count += 1
        stats.bytes += len(payload)
        stats.last_ns = received_ns
        try:
            stats.schema = common.decode_for(keys, key, payload).schema
        except ProtocolError as exc:
            stats.malformed += 1
            stats.error = str(exc)

    bus.subscribe(keys.everything, on_sample, latest=False, max_queue=1 << 16)
    await asyncio.sleep(args.seconds)
    if not seen:
        print(f"no samples on {keys.everything} in {args.seconds:g}s", file=out)
        return 1
    width = max(len(k) for k in seen)
    print(f"{'KEY':{width}}  {'COUNT':>6}  {'RATE':>9}  SCHEMA", file=out)
    for key in sorted(seen):
        s = seen[key]
        rate = f"{s.count / args.seconds:7.1f}Hz"
        line = f"{key:{width}}  {s.count:6d}  {rate:>9}  {s.schema}"
        if s.malformed:
            line += f"  ({s.malformed} malformed: {s.error})"
        print(line, file=out)
    return 0


def add_info_parser(sub: Any, connection: argparse.ArgumentParser) -> None:
    """``info``: what a key carries and who publishes it."""
    info = sub.add_parser(
        "info", parents=[connection], help="what a key carries: schema, fields, publishers, rate",
        description="Print the declared topic(s) a key belongs to (schema, every field with "
                    "its type and bounds), its publishers — the live components (liveliness "
                    "tokens) whose heartbeat announces the key — and what was heard on it over "
                    "--seconds: messages, rate, and each publisher by its pub id, named by the "
                    "component announcing it.")
    info.add_argument("key", metavar="KEY", help=common.KEY_HELP)
    info.add_argument("--seconds", type=float, default=1.0, metavar="S",
                      help="how long to listen, at least 1 s: two heartbeats of every "
                           "component (default: 1)")


async def cmd_info(bus: Bus, args: argparse.Namespace, out: TextIO) -> int:
    key_expr = common.key_or_report(bus.keys, args.key)
    if key_expr is None:
        return 2
    seen: dict[str, samples.KeyWindow] = {}

    def on_sample(key: str, payload: bytes, received_ns: int) -> None:
        window = seen.setdefault(key, samples.KeyWindow(1000))
        window.add(received_ns, payload)
        with contextlib.suppress(ProtocolError):
            pub = decode(payload).pub
            if pub is not None and len(window.publishers) < 64:
                window.publishers.add(pub)

    monitor = HealthMonitor(bus)  # the heartbeats: what each component announces
    monitor.start()
    bus.subscribe(key_expr, on_sample, latest=False, max_queue=1 << 16)
    print_declared(bus.keys, key_expr, out)
    out.flush()
    # Heartbeats come every 0.5 s: listening at least a second hears every live component.
    listen_s = max(args.seconds, 1.0)
    await asyncio.sleep(listen_s)
    await monitor.heard_from_all(common.HEARD_WITHIN_S)
    tokens = await bus.alive_tokens(bus.keys.all_alive, timeout_s=args.timeout)
    monitor.close()
    # What the monitor's own liveliness subscription saw counts too: a query for the tokens
    # can come back short on a busy machine.
    alive = {bus.keys.component_of_alive(t) for t in tokens} | set(monitor.alive_names())
    publishers = common.announcing(monitor, key_expr, alive)
    print(format_publishers(publishers, alive=alive, announcing={
        c for c, health in monitor.components.items() if health.publishes}), file=out)
    by_pub = {p.pub: component for component, found in publishers.items() for p in found}
    if not seen:
        print(f"heard: nothing on {key_expr} in {listen_s:g}s", file=out)
        return 0
    for key in sorted(seen):
        window = seen[key]
        ids = sorted(window.publishers)
        named = [f"{by_pub[i]} (pub {i})" if i in by_pub else f"pub {i}, announced by no live "
                 f"component" for i in ids]
        print(f"heard on {key}: {window.count} messages in {listen_s:g}s "
              f"({window.count / listen_s:.1f} Hz), from {len(ids)} publisher(s)"
              + (f": {'; '.join(named)}" if named else ""), file=out)
    return 0


def print_declared(keys: Keys, key_expr: str, out: TextIO) -> None:
    """The first part of ``info``: the declared topics ``key_expr`` belongs to, each with its
    schema and every field with its type and bounds."""
    declared = [t for t in topics.TOPICS if intersects(t.key_expr(keys), key_expr)]
    print(f"key: {key_expr}", file=out)
    if not declared:
        print("declared topic: none (an undeclared kind: any schema, data a map of plain "
              "values; docs/protocol.md)", file=out)
    for topic in declared:
        print(f"declared topic: {topic.name} — {topic.doc}\n  key: {topic.key_expr(keys)}"
              f"\n  schema: {topic.schema}", file=out)
        rows = reference.field_rows(topic)
        for name, given, kind in rows:  # as docs/protocol.md's reference has them
            print(f"  {reference.plain(name)}: {reference.plain(kind)} "
                  f"({reference.plain(given)})", file=out)
        if not rows and topic.type is topics.PlainData:
            print("  data: a map of plain values (checked generically)", file=out)


def format_publishers(publishers: dict[str, list[topics.Published]], *, alive: set[str],
                      announcing: set[str]) -> str:
    """The ``publishers`` line of ``info``: the live components whose heartbeat announces the
    key, and how many live components announce no publisher at all (they may publish it
    unannounced)."""
    silent = len(alive - announcing)
    unsaid = (f"; {silent} of the {len(alive)} live components announce no publisher (they "
              f"publish nothing, or do not say so in their heartbeat: docs/protocol.md)"
              if silent else "")
    if not publishers:
        return f"publishers (live components announcing it): none{unsaid}"
    names = ", ".join(
        f"{component} ({', '.join(p.key.removeprefix('ubf/') for p in found)})"
        for component, found in sorted(publishers.items()))
    return f"publishers (live components announcing it): {names}{unsaid}"
