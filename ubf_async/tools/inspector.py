"""``python -m ubf_async.inspector`` — look into a running robot from the command line.

ROS-2-like subcommands, each a separate short-lived zenoh session:

* ``robots`` — every robot alive on the network (a fleet's router): components, tick rates,
  who wins;
* ``components`` — the live components: one name per line, sorted, from the liveliness
  tokens ``ubf/<robot>/alive/*`` (``--long`` adds heartbeat health);
* ``keys`` — the keys that carry samples, with message counts and rates over ``--seconds``;
* ``echo KEY`` — samples on a key (or key expression), decoded and validated like the robot
  does; malformed payloads are printed as errors, never crash the tool;
* ``state`` — the controller's view: tick rate, drive command, every source with its age
  (and whether it is stale), and the last tick's explanation (who voted what, who won);
* ``tree show | set-arbiter | set-child | load`` — the running behaviour tree, and live
  changes to it through the robot's tree service (``ubf/<robot>/tree``, docs/protocol.md,
  "Live tree changes"). Exit status 1 when the robot refuses a change (it then keeps its
  tree as it was), 2 when no robot answers.

It joins the robot as a zenoh **client** of the endpoint it connects to (default
``tcp/127.0.0.1:7447``, where ``python -m ubf_async.launch`` listens), so the robot's peer
answers for every process attached to it. It declares no liveliness token: it never shows up
in ``components``.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import dataclasses
import difflib
import itertools
import json
import statistics
import sys
import time
from collections import deque
from collections.abc import Awaitable, Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import msgpack
import msgspec
import yaml

from ubf_async.cli.args import add_connection_arguments, connection_options
from ubf_async.cli.run import STOP_SIGNALS, run_main
from ubf_async.errors import UbfError
from ubf_async.net.options import DEFAULT_LISTEN
from ubf_async.net.transport import intersects
from ubf_async.runtime import clockdomain
from ubf_async.runtime.bus import Bus, QueryError, wait_for_robot
from ubf_async.runtime.component import HealthMonitor
from ubf_async.services.live import encode_request, render_tree_data
from ubf_async.services.live import request as tree_request
from ubf_async.services.status import tick_rates
from ubf_async.wire import topics
from ubf_async.wire.protocol import (
    MAX_PAYLOAD_BYTES,
    ROOT,
    Keys,
    Message,
    ProtocolError,
    decode,
    encode,
)

PROG = "python -m ubf_async.inspector"
MAX_TICK_KINDS = 16
"""Kinds of tick ``hz`` keeps apart per key (a reflex or trigger source each makes one)."""
ECHO_QUIET_S = 2.0
"""How long ``echo`` hears nothing before it says whether anything publishes the key: four
heartbeats of every component, which announce what each publishes."""
HEARD_WITHIN_S = 5.0
"""How much longer ``echo`` and ``info`` wait, at most, for a heartbeat of every live
component before they say who publishes what (on a busy machine they can be late)."""

def expected_schema(keys: Keys, key: str) -> str | None:
    """The schema a key requires (``cmd/drive`` → ``drive``, ``sensor/camera/x`` →
    ``camera.seekcolor``), from :mod:`ubf_async.wire.topics`; ``None`` where any is allowed (a
    kind of sensor not declared there, a status key)."""
    schemas = {topic.schema for topic in topics.matching(keys, key)}
    return schemas.pop() if len(schemas) == 1 else None


def decode_for(keys: Keys, key: str, payload: bytes) -> Message:
    """Decode and validate a sample as its key requires (raises :class:`ProtocolError`)."""
    return decode(payload, schema=expected_schema(keys, key))


def resolve_key(keys: Keys, key: str) -> str:
    """``sensor/range/front`` → ``ubf/<robot>/sensor/range/front``; full keys stay as they are."""
    key = key.strip().strip("/")
    if not key:
        raise ValueError("empty key")
    return key if key.startswith("ubf/") or key.startswith("**") else f"{keys.prefix}/{key}"


def _jsonable(value: Any) -> Any:
    if isinstance(value, msgspec.Struct):  # a typed message: its fields as on the wire
        return _jsonable(msgspec.to_builtins(value))
    if isinstance(value, bytes):
        return value.hex()
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    return value


def _json(value: Any) -> str:
    return json.dumps(_jsonable(value), ensure_ascii=False)


# ---------------------------------------------------------------------------------------------
# Command line


def _common_parser(*, suppress: bool = False) -> argparse.ArgumentParser:
    """The connection flags. ``suppress``: defaults left out, for the subcommands, so that
    flags given before the subcommand (parsed by the top level, with the defaults) are not
    overwritten by the subcommand's defaults — the flags work before or after it."""
    common = argparse.ArgumentParser(add_help=False)
    add_connection_arguments(common, default_connect=[DEFAULT_LISTEN])
    for action in common._actions:  # the tool's default mode differs from a component's
        if action.dest == "mode":
            action.default = "client"
            action.help = ("zenoh session mode (default: client — the robot's peer then "
                           "answers for every process attached to it)")
    common.add_argument("--timeout", type=float, default=5.0, metavar="S",
                        help="how long to wait for the robot to answer (default: 5)")
    if suppress:
        for action in common._actions:
            if not isinstance(action, argparse._VersionAction):
                action.default = argparse.SUPPRESS
    return common


def build_parser() -> argparse.ArgumentParser:
    common = _common_parser(suppress=True)
    parser = argparse.ArgumentParser(
        prog=PROG, parents=[_common_parser()],
        description="Inspect a running ubf_async robot over zenoh: its live components, "
                    "its keys and their rates, decoded samples, and the controller's state "
                    "with the last tick's explanation.",
        epilog=f"examples:\n  {PROG} components --connect tcp/127.0.0.1:7447\n"
               f"  {PROG} keys --seconds 3\n"
               f"  {PROG} echo sensor/range/front --count 5\n"
               f"  {PROG} echo 'cmd/**' --json\n"
               f"  {PROG} state --robot mini\n"
               f"  {PROG} tree show\n"
               f"  {PROG} tree set-arbiter seek_pink_ball MonteCarlo --param hold_ticks=5\n"
               f"  {PROG} tree set-child seek_pink_ball chase --priority 3\n"
               f"  {PROG} tree load my-tree.yaml\n"
               f"  {PROG} hz cmd/drive\n"
               f"  {PROG} bw 'sensor/**'\n"
               f"  {PROG} info sensor/camera/front\n"
               f"  {PROG} pub cmd/leds '{{mask: 1}}'\n"
               f"  {PROG} state --watch\n"
               f"connection flags (--connect, --robot, ...) go before or after COMMAND.\n"
               f"run `{PROG} COMMAND --help` for a command's options.",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    components = sub.add_parser(
        "components", parents=[common], help="list the live components (liveliness tokens)",
        description="List the robot's live components: one name per line, sorted, from the "
                    "liveliness tokens ubf/<robot>/alive/*. Exactly those whose token is "
                    "present now; a killed process disappears as soon as its session ends.",
    )
    components.add_argument("--long", "-L", action="store_true",
                            help="also listen to heartbeats for --heartbeat-s and show health")
    components.add_argument("--heartbeat-s", type=float, default=1.2, metavar="S",
                            help="with --long: how long to listen for heartbeats")
    keys = sub.add_parser(
        "keys", parents=[common], help="list the keys carrying samples, with rates",
        description="Listen to ubf/<robot>/** for --seconds and list every key that carried "
                    "samples: count, rate, schema of the last sample, malformed payloads.",
    )
    keys.add_argument("--seconds", type=float, default=2.0, metavar="S",
                      help="how long to listen (default: 2)")
    echo = sub.add_parser(
        "echo", parents=[common], help="print the samples of a key, decoded",
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
    echo.add_argument("--raw", action="store_true",
                      help="print the msgpack map as it came, without validation")
    echo.add_argument("--json", action="store_true", help="one JSON object per line")
    state = sub.add_parser(
        "state", parents=[common], help="the controller's state and last tick's explanation",
        description="Wait for the controller's status (ubf/<robot>/status/<controller>) and "
                    "print its tick rate, drive command, sources with ages, and the last "
                    "tick's explanation: every behaviour's vote, '*' marking the winners.",
    )
    state.add_argument("--controller", default="controller", metavar="NAME",
                       help="the controller component's name (default: controller)")
    state.add_argument("--json", action="store_true", help="print the status as JSON")
    add_watch_arguments(state)
    robots = sub.add_parser(
        "robots", parents=[common], help="list the live robots on a router (a fleet)",
        description="List every robot alive on the zenoh network this joins (a fleet's "
                    "router, docs/fleet.md), whatever --robot says: its live components "
                    "(liveliness tokens ubf/*/alive/*) and, from its controller's status "
                    "heard over --seconds, the tick rate (all ticks, and those of the "
                    "periodic clock), mode and who wins the drive command now.")
    robots.add_argument("--seconds", type=float, default=1.2, metavar="S",
                        help="how long to listen for the controllers' status (published "
                             "every 0.5 s)")
    robots.add_argument("--json", action="store_true", help="print the list as JSON")
    add_tree_parser(sub, common)
    add_rate_parsers(sub, common)
    return parser


def add_watch_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--watch", "-w", action="store_true",
                        help="refresh in place (one block per refresh when not a terminal)")
    parser.add_argument("--interval", type=float, default=1.0, metavar="S",
                        help="with --watch: seconds between refreshes (default: 1)")
    parser.add_argument("--count", "-n", type=int, default=0, metavar="N",
                        help="with --watch: stop after N refreshes (default: until Ctrl-C)")


def add_rate_parsers(sub: Any, common: argparse.ArgumentParser) -> None:
    key_help = ("a key or key expression, relative to ubf/<robot>/ unless it starts with ubf/ "
                "(e.g. cmd/drive, 'sensor/**')")
    for name, what in (("hz", "the rate of a key's messages (like ros2 topic hz)"),
                       ("bw", "the bandwidth of a key's messages (like ros2 topic bw)")):
        verb = sub.add_parser(
            name, parents=[common], help=what,
            description=f"Print {what}, once a second, one line per key: over the last "
                        f"--window messages of each key.")
        verb.add_argument("key", metavar="KEY", help=key_help)
        verb.add_argument("--window", type=int, default=100, metavar="N",
                          help="messages each figure is computed over (default: 100)")
        verb.add_argument("--count", "-n", type=int, default=0, metavar="N",
                          help="stop after N reports (default: until Ctrl-C)")
        verb.add_argument("--seconds", type=float, default=None, metavar="S",
                          help="stop after S seconds")
    info = sub.add_parser(
        "info", parents=[common], help="what a key carries: schema, fields, publishers, rate",
        description="Print the declared topic(s) a key belongs to (schema, every field with "
                    "its type and bounds), its publishers — the live components (liveliness "
                    "tokens) whose heartbeat announces the key — and what was heard on it over "
                    "--seconds: messages, rate, and each publisher by its pub id, named by the "
                    "component announcing it.")
    info.add_argument("key", metavar="KEY", help=key_help)
    info.add_argument("--seconds", type=float, default=1.0, metavar="S",
                      help="how long to listen, at least 1 s: two heartbeats of every "
                           "component (default: 1)")
    pub = sub.add_parser(
        "pub", parents=[common], help="publish a message on a key, checked first",
        description="Publish DATA (YAML or JSON: a map of the message's fields) on KEY, "
                    "checked first exactly as the robot checks it: a message the robot would "
                    "refuse (an unknown field, a value out of range) is refused here with the "
                    "reason, and nothing is sent (exit status 2). Stamped on the robot's "
                    "clock. In secure mode only identities allowed to publish on KEY can.")
    pub.add_argument("key", metavar="KEY",
                     help="one key (not a key expression), relative to ubf/<robot>/ unless it "
                          "starts with ubf/ (e.g. cmd/leds, sensor/range/left)")
    pub.add_argument("data", metavar="DATA", help="e.g. '{speed: 20, turn: 0}'")
    pub.add_argument("--schema", default=None,
                     help="the schema name, for a key no declared topic covers")
    pub.add_argument("--rate", "-r", type=float, default=None, metavar="HZ",
                     help="publish at HZ until Ctrl-C or SIGTERM (or --count messages), like "
                          "ros2 topic pub -r")
    pub.add_argument("--count", "-n", type=int, default=None, metavar="N",
                     help="how many messages (default: 1 without --rate, until stopped with "
                          "it)")


def param(text: str) -> tuple[str, Any]:
    """``--param KEY=VALUE``: VALUE is read as YAML (``3`` an int, ``true`` a bool, ``[1, 2]``
    a list, anything else a string)."""
    key, sep, value = text.partition("=")
    key = key.strip()
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"{text!r}: expected KEY=VALUE, e.g. hold_ticks=5")
    try:
        return key, yaml.safe_load(value) if value.strip() else ""
    except yaml.YAMLError as exc:
        raise argparse.ArgumentTypeError(f"{text!r}: VALUE is not valid YAML: {exc}") from None


def add_tree_parser(sub: Any, common: argparse.ArgumentParser) -> None:
    tree = sub.add_parser(
        "tree", parents=[common], help="show the running behaviour tree, or change it live",
        description="Show the robot's running behaviour tree or change it while it runs, "
                    "through its tree service (ubf/<robot>/tree; docs/protocol.md, 'Live tree "
                    "changes'). A change applies between two ticks, after the robot has "
                    "validated it; a refused change leaves the tree as it was. Exit status: "
                    "0 done, 1 refused by the robot, 2 no robot answered.",
    )
    verbs = tree.add_subparsers(dest="tree_command", required=True, metavar="VERB")
    show = verbs.add_parser("show", parents=[common], help="print the running tree",
                            description="Print the running tree: composites with their "
                                        "arbiter, children with [p=priority w=weight].")
    arbiter = verbs.add_parser(
        "set-arbiter", parents=[common], help="swap a composite's arbiter",
        description="Give COMPOSITE a new arbiter, e.g. HighestPriority, or MonteCarlo with "
                    "--param hold_ticks=5. The robot builds it and checks it against the "
                    "composite's children first.")
    arbiter.add_argument("composite", metavar="COMPOSITE")
    arbiter.add_argument("arbiter", metavar="ARBITER",
                         help="a registered arbiter name or a 'module:factory' reference")
    arbiter.add_argument("--param", "-p", type=param, action="append", default=[],
                         metavar="KEY=VALUE",
                         help="a parameter of the arbiter (repeatable; VALUE is read as YAML)")
    child = verbs.add_parser(
        "set-child", parents=[common], help="change a child's priority and/or weight",
        description="Change the priority and/or weight of CHILD in COMPOSITE.")
    child.add_argument("composite", metavar="COMPOSITE")
    child.add_argument("child", metavar="CHILD")
    child.add_argument("--priority", type=int, default=None, metavar="N")
    child.add_argument("--weight", type=float, default=None, metavar="W")
    load = verbs.add_parser(
        "load", parents=[common], help="replace the whole tree from a robot-file fragment",
        description="Replace the running tree with the one FRAGMENT describes: a robot file's "
                    "`tree:` node (docs/robot-file.md), alone or as `tree: ...`. Every "
                    "behaviour, arbiter and parameter is checked before the new tree takes "
                    "over.")
    load.add_argument("fragment", type=Path, metavar="FRAGMENT.yaml")
    for verb in (show, arbiter, child, load):
        verb.add_argument("--json", action="store_true", help="print the reply as JSON")
    add_watch_arguments(show)


# ---------------------------------------------------------------------------------------------
# Commands


async def open_bus(args: argparse.Namespace) -> Bus:
    """Open a session and wait until it reaches the robot: :class:`NoRobotError` (one line:
    nothing answered, or the robot there has another name) after ``--timeout``."""
    options = connection_options(args)
    bus = await Bus.open(options)
    try:
        await wait_for_robot(bus, timeout_s=args.timeout,
                             any_robot=args.command == "robots")
    except BaseException:
        await bus.aclose()
        raise
    return bus


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
            detail = "no heartbeat (not a ubf_async component, or none yet)"
        else:
            state = "healthy" if health.healthy(now) else "UNHEALTHY"
            detail = (f"{state}: heartbeat {now - health.last_heartbeat_s:.2f}s ago, "
                      f"restarts {health.restarts}, loop lag {health.loop_lag_s * 1e3:.1f}ms")
        print(f"{name:24} {detail}", file=out)
    monitor.close()
    return 0


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
            stats.schema = decode_for(keys, key, payload).schema
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


def format_sample(keys: Keys, key: str, payload: bytes, *, raw: bool, as_json: bool) -> str:
    """One line for one sample: decoded (or raw) fields, or the reason it was rejected."""
    if raw:
        try:
            if len(payload) > MAX_PAYLOAD_BYTES:
                raise ValueError(f"{len(payload)} bytes exceeds {MAX_PAYLOAD_BYTES}")
            value = msgpack.unpackb(payload, raw=False, strict_map_key=False)
        except Exception as exc:  # any unpacker failure is the payload's, not ours
            error = f"not msgpack: {exc}"
            return _json({"key": key, "error": error}) if as_json else f"{key} ERROR {error}"
        return _json({"key": key, "raw": value}) if as_json else f"{key} RAW {_json(value)}"
    try:
        message = decode_for(keys, key, payload)
    except ProtocolError as exc:
        return _json({"key": key, "error": str(exc)}) if as_json else f"{key} ERROR {exc}"
    if as_json:
        return _json({"key": key, "schema": message.schema, "seq": message.seq,
                      "stamp_ns": message.stamp_ns, "period_s": message.period_s,
                      "data": message.data})
    period = f" period {message.period_s:g}s" if message.period_s is not None else ""
    return (f"{key} {message.schema} #{message.seq} stamp {message.stamp_ns}{period}: "
            f"{_json(message.data)}")


async def cmd_echo(bus: Bus, args: argparse.Namespace, out: TextIO) -> int:
    keys = bus.keys
    try:
        key_expr = resolve_key(keys, args.key)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
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
            await monitor.heard_from_all(HEARD_WITHIN_S)
            if shown == 0:
                print(await unpublished(bus, monitor, key_expr), file=sys.stderr, flush=True)

    started = asyncio.get_running_loop().time()
    note = asyncio.create_task(say_if_unpublished())
    try:
        with contextlib.suppress(TimeoutError):  # --seconds elapsed
            await asyncio.wait_for(done.wait(), args.seconds)
        if (not note.done() and shown == 0
                and asyncio.get_running_loop().time() - started >= ECHO_QUIET_S):
            # --seconds ended while the note waited for heartbeats: say what is known.
            note.cancel()
            print(await unpublished(bus, monitor, key_expr), file=sys.stderr, flush=True)
    finally:
        note.cancel()
        monitor.close()
    return 0 if not args.count or shown >= args.count else 1


async def unpublished(bus: Bus, monitor: HealthMonitor, key_expr: str) -> str:
    """What ``echo`` says on stderr when nothing has arrived on ``key_expr``: whether a live
    component announces publishing it (heartbeats, docs/protocol.md), and the keys they do
    announce that look like it. It goes on waiting."""
    tokens = await bus.alive_tokens(bus.keys.all_alive, timeout_s=1.0)
    alive = {bus.keys.component_of_alive(t) for t in tokens} | set(monitor.alive_names())
    publishers = announcing(monitor, key_expr, alive)
    if publishers:
        return (f"# nothing on {key_expr} yet, though {', '.join(sorted(publishers))} "
                f"announce{'s' if len(publishers) == 1 else ''} publishing it (it may publish "
                f"only on a change); still waiting")
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
            + "; still waiting (`inspector keys` lists what is published)")


def format_state(status: dict[str, Any], *, robot: str, controller: str,
                 status_age_s: float | None) -> str:
    def num(value: Any, fmt: str, default: str = "--") -> str:
        return format(value, fmt) if isinstance(value, int | float) else default

    lines = []
    age = f", status {status_age_s * 1e3:.0f} ms old" if status_age_s is not None else ""
    mode = str(status.get("mode", "?"))
    # The status line's labels: the clock's ticks apart from the reflex ticks (periodic), or
    # one tick per sample (sync, event).
    rates = tick_rates(mode, _number(status.get("rate_hz")),
                       _number(status.get("periodic_rate_hz")))
    target = _number(status.get("rate_hz_target"))
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
        why = s.get("stale_why")
        stale = ("" if not s.get("stale") else f"  STALE: quiet {why}" if why else "  STALE")
        age_s = s.get("age_s")
        age_ms = age_s * 1e3 if isinstance(age_s, int | float) else None
        refused = s.get("refused")
        refused_text = f"  refused {refused}" if refused else ""
        lines.append(f"  {s.get('source', '?')!s:{width}}  age {num(age_ms, '7.0f'):>7} ms"
                     f"  {s.get('schema', '')}{stale}{refused_text}")
    refusals = {k: v for k, v in (status.get("refused") or {}).items() if v}
    if refusals:
        lines.append("refused: " + ", ".join(f"{k} {v}" for k, v in refusals.items()))
    lines.extend(format_clock_domain(status.get("clock_domain")))
    quarantined = status.get("quarantined") or []
    if quarantined:
        lines.append("quarantined (failing tick after tick, cut off): " + ", ".join(quarantined))
    explanation = status.get("explanation") or "(no tick yet)"
    lines.append("last tick ('*' = won; [p=priority w=weight] <arbiter>):")
    lines.extend(f"  {line}" for line in str(explanation).splitlines())
    return "\n".join(lines)


def format_clock_domain(foreign: Any) -> list[str]:
    """The status's ``clock_domain`` (:mod:`ubf_async.runtime.clockdomain`): sources whose stamps
    are on another clock than the robot's, so their ages mean nothing."""
    if not isinstance(foreign, list) or not foreign:
        return []
    lines = ["stamped on another clock (ages meaningless; see docs/protocol.md "
             "'The robot clock'):"]
    for f in foreign:
        if isinstance(f, dict):
            offset = f.get("offset_s")
            off = f"{offset:+.3g} s" if isinstance(offset, int | float) else "?"
            lines.append(f"  {f.get('source', '?')}  {f.get('samples', '?')} samples, "
                         f"like {clockdomain.the(str(f.get('clock', '?')))}, last {off} off")
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
            print(f"error: no status on {key} within {args.timeout:g}s{why}: is the robot's "
                  f"controller running (--controller, --robot)?", file=sys.stderr)
            return None
        arrived.clear()
        message = latest[-1]
        if args.json:
            return _json({"key": key, "stamp_ns": message.stamp_ns, "status": message.data})
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


def tree_request_data(args: argparse.Namespace) -> dict[str, Any]:
    """The ``tree.request`` data a ``tree`` verb sends (ValueError for unusable input)."""
    verb = args.tree_command
    if verb == "show":
        return {"op": "show"}
    if verb == "set-arbiter":
        params = dict(args.param)
        return {"op": "set_arbiter", "composite": args.composite,
                "arbiter": {"type": args.arbiter, "params": params} if params else args.arbiter}
    if verb == "set-child":
        if args.priority is None and args.weight is None:
            raise ValueError("set-child: give --priority and/or --weight")
        data: dict[str, Any] = {"op": "set_child", "composite": args.composite,
                                "child": args.child}
        if args.priority is not None:
            data["priority"] = args.priority
        if args.weight is not None:
            data["weight"] = args.weight
        return data
    try:
        fragment = args.fragment.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"{args.fragment}: cannot read it: {exc}") from None
    # Long fragments travel as UTF-8 bytes: protocol strings are at most 4096 characters.
    return {"op": "load", "tree": fragment if len(fragment) <= 4096 else fragment.encode()}


async def cmd_tree(bus: Bus, args: argparse.Namespace, out: TextIO) -> int:
    try:
        data = tree_request_data(args)
        encode_request(data, stamp_ns=0)  # refuse what the robot would refuse, before sending
    except ValueError as exc:  # ProtocolError is a ValueError
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if getattr(args, "watch", False):
        async def block() -> str | None:
            code, text = await _tree_once(bus, args, data)
            if code:
                print(text, file=sys.stderr)
                return None
            return text

        return 2 if await watch(block, args, out) else 0
    code, text = await _tree_once(bus, args, data)
    print(text, file=sys.stderr if code else out)
    return code


async def _tree_once(bus: Bus, args: argparse.Namespace, data: dict[str, Any]
                     ) -> tuple[int, str]:
    """One tree request: the exit status and what to print."""
    try:
        reply = await tree_request(bus, data, timeout_s=args.timeout)
    except TimeoutError:
        return 2, (f"error: no robot {bus.robot!r} answered on ubf/{bus.robot}/tree within "
                   f"{args.timeout:g}s: is it running, with its tree service (--robot, "
                   f"--connect)?")
    except (QueryError, ProtocolError) as exc:
        return 2, f"error: robot {bus.robot!r} gave no usable reply: {exc}"
    if not reply["ok"]:
        return 1, (f"error: robot {bus.robot!r} refused {args.tree_command}: "
                   f"{reply['error']} (tree unchanged, version {reply.get('version', '?')})")
    if args.json:
        return 0, _json(reply)
    version = reply.get("version", "?")
    lines = [f"robot {bus.robot!r}: tree version {version}" if args.tree_command == "show"
             else f"robot {bus.robot!r}: {args.tree_command} applied, tree version {version}",
             render_tree_data(reply["tree"])]
    lines.extend(f"remote slot {slot['composite']}/{slot['name']} [p={slot['priority']} "
                 f"w={slot['weight']:g}]" for slot in reply.get("slots") or ())
    return 0, "\n".join(lines)


# ---------------------------------------------------------------------------------------------
# hz, bw, info, pub


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
    try:
        key_expr = resolve_key(bus.keys, args.key)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.window < 2:
        print("error: --window must be at least 2", file=sys.stderr)
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


def describe_type(info: msgspec.inspect.Type) -> str:
    """A field's type with its bounds, as a reader of the protocol wants them."""
    mi = msgspec.inspect
    if isinstance(info, mi.UnionType):
        return " | ".join(describe_type(t) for t in info.types)
    if isinstance(info, mi.NoneType):
        return "nil"
    if isinstance(info, mi.LiteralType):
        return " | ".join(json.dumps(v) for v in info.values)
    bounds = []
    for name, sign in (("ge", "≥"), ("gt", ">"), ("le", "≤"), ("lt", "<")):
        value = getattr(info, name, None)
        if value is not None:
            bounds.append(f"{sign} {value:g}" if isinstance(value, float) else f"{sign} {value}")
    for name, sign in (("min_length", "length ≥"), ("max_length", "length ≤")):
        value = getattr(info, name, None)
        if value is not None:
            bounds.append(f"{sign} {value}")
    if isinstance(info, mi.VarTupleType | mi.ListType):
        base = f"array of {describe_type(info.item_type)}"
    elif isinstance(info, mi.TupleType):
        base = "[" + ", ".join(describe_type(t) for t in info.item_types) + "]"
    elif isinstance(info, mi.StructType):
        base = "map {" + ", ".join(f.name for f in info.fields) + "}"
    elif isinstance(info, mi.DictType):
        base = "map"
    else:
        base = {mi.IntType: "int", mi.FloatType: "number", mi.StrType: "str",
                mi.BoolType: "bool", mi.BytesType: "bytes"}.get(type(info), type(info).__name__)
    return base + (f" ({', '.join(bounds)})" if bounds else "")


def announcing(monitor: HealthMonitor, key_expr: str, alive: set[str]
               ) -> dict[str, list[topics.Published]]:
    """The live components whose newest heartbeat announces a key matching ``key_expr``
    (``publishes``, docs/protocol.md), with what they announce there (a component whose
    liveliness token is gone is not a publisher any more)."""
    found: dict[str, list[topics.Published]] = {}
    for component, health in monitor.components.items():
        if component in alive and (
                hits := [p for p in health.publishes if intersects(key_expr, p.key)]):
            found[component] = hits
    return found


async def cmd_info(bus: Bus, args: argparse.Namespace, out: TextIO) -> int:
    try:
        key_expr = resolve_key(bus.keys, args.key)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    seen: dict[str, KeyWindow] = {}

    def on_sample(key: str, payload: bytes, received_ns: int) -> None:
        window = seen.setdefault(key, KeyWindow(1000))
        window.add(received_ns, payload)
        with contextlib.suppress(ProtocolError):
            pub = decode(payload).pub
            if pub is not None and len(window.publishers) < 64:
                window.publishers.add(pub)

    monitor = HealthMonitor(bus)  # the heartbeats: what each component announces
    monitor.start()
    bus.subscribe(key_expr, on_sample, latest=False, max_queue=1 << 16)
    declared = [t for t in topics.TOPICS if intersects(t.key_expr(bus.keys), key_expr)]
    print(f"key: {key_expr}", file=out)
    if not declared:
        print("declared topic: none (an undeclared kind: any schema, data a map of plain "
              "values; docs/protocol.md)", file=out)
    for topic in declared:
        print(f"declared topic: {topic.name} — {topic.doc}\n  key: {topic.key_expr(bus.keys)}"
              f"\n  schema: {topic.schema}", file=out)
        type_info = msgspec.inspect.type_info(topic.type)
        if isinstance(type_info, msgspec.inspect.StructType):
            for f in type_info.fields:
                need = "" if f.required else " (optional)"
                print(f"  {f.name}: {describe_type(f.type)}{need}", file=out)
        else:
            print("  data: a map of plain values (checked generically)", file=out)
    out.flush()
    # Heartbeats come every 0.5 s: listening at least a second hears every live component.
    listen_s = max(args.seconds, 1.0)
    await asyncio.sleep(listen_s)
    await monitor.heard_from_all(HEARD_WITHIN_S)
    tokens = await bus.alive_tokens(bus.keys.all_alive, timeout_s=args.timeout)
    monitor.close()
    # What the monitor's own liveliness subscription saw counts too: a query for the tokens
    # can come back short on a busy machine.
    alive = {bus.keys.component_of_alive(t) for t in tokens} | set(monitor.alive_names())
    publishers = announcing(monitor, key_expr, alive)
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


async def cmd_pub(bus: Bus, args: argparse.Namespace, out: TextIO) -> int:
    try:
        key = resolve_key(bus.keys, args.key)
        if "*" in key:
            raise ValueError(f"{args.key}: pub needs one key, not a key expression")
        data = yaml.safe_load(args.data)
        if not isinstance(data, dict):
            raise ValueError(f"DATA must be a map of the message's fields, got {args.data!r}")
        schema = args.schema or expected_schema(bus.keys, key)
        if schema is None:
            raise ValueError(f"{key}: no declared topic covers this key; give --schema NAME")
        required = expected_schema(bus.keys, key)
        if required is not None and schema != required:
            raise ValueError(f"{key} takes schema {required!r}, not {schema!r}")
        encode(schema, data, stamp_ns=0, seq=1)  # the robot's checks, before anything is sent
        fields = topic.fields if (topic := topics.BY_SCHEMA.get(schema)) else ()
        unknown = sorted(map(str, set(data) - set(fields))) if fields else []
        if unknown:  # the robot ignores unknown fields: a typo would go unnoticed
            raise ValueError(f"{schema} has no field(s) {', '.join(unknown)} (the robot would "
                             f"ignore them); its fields: {', '.join(fields)}")
    except (ValueError, yaml.YAMLError) as exc:  # ProtocolError is a ValueError
        print(f"error: refused, nothing sent: {exc}", file=sys.stderr)
        return 2
    if args.rate is not None and not args.rate > 0:
        print("error: --rate must be > 0", file=sys.stderr)
        return 2
    if args.count is not None and args.count < 1:
        print("error: --count must be at least 1", file=sys.stderr)
        return 2
    count = args.count if args.count is not None else (None if args.rate else 1)
    await clockdomain.follow_robot_clock(bus, mode="auto")
    publisher = bus.publisher(key, schema)
    with contextlib.suppress(TimeoutError):  # nobody listening yet: publish all the same
        await publisher.wait_for_subscribers(timeout_s=min(args.timeout, 2.0))
    sent = 0
    with _stopped_by_signals() as stopped:
        started = time.monotonic()
        while not stopped.is_set():
            publisher.publish(data)
            sent += 1
            if count is not None and sent >= count:
                break
            # Paced on the schedule, not from the last send, so the rate does not drift.
            delay = started + sent / (args.rate or 10.0) - time.monotonic()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(stopped.wait(), max(0.0, delay))
    print(f"sent {sent} {schema} message(s) on {key}"
          + (" (stopped)" if stopped.is_set() else ""), file=out)
    return 0


@contextlib.contextmanager
def _stopped_by_signals() -> Iterator[asyncio.Event]:
    """An event set by the first Ctrl-C or SIGTERM while inside (the normal end of a
    ``pub --rate``: the count sent is still printed); the handlers are removed on exit."""
    loop = asyncio.get_running_loop()
    stopped = asyncio.Event()
    for signum in STOP_SIGNALS:
        loop.add_signal_handler(signum, stopped.set)
    try:
        yield stopped
    finally:
        for signum in STOP_SIGNALS:
            loop.remove_signal_handler(signum)


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
        row.tick_hz = _number(status.get("rate_hz"))
        row.periodic_hz = _number(status.get("periodic_rate_hz"))
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
        print(_json({"robots": [dataclasses.asdict(row) for row in listed]}), file=out)
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


def _number(value: Any) -> float | None:
    return float(value) if isinstance(value, int | float) else None


COMMANDS = {"robots": cmd_robots, "components": cmd_components, "keys": cmd_keys, "echo": cmd_echo,
            "state": cmd_state, "tree": cmd_tree, "hz": cmd_rate, "bw": cmd_rate,
            "info": cmd_info, "pub": cmd_pub}


async def run(args: argparse.Namespace, out: TextIO = sys.stdout) -> int:
    try:
        bus = await open_bus(args)
    except (UbfError, ConnectionError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    try:
        return await COMMANDS[args.command](bus, args, out)
    except BrokenPipeError:  # `... | head`
        return 0
    finally:
        await bus.aclose()


def main(argv: Sequence[str] | None = None) -> int:
    """Ends as every command does (README): the first Ctrl-C or SIGTERM ends a watching
    command (``state --watch``, ``hz``, ``echo``) with status 0, a second at once (130)."""
    args = build_parser().parse_args(argv)
    out = sys.stdout  # itself, not run_main's guarded stream: `... | head` ends the command
    return run_main(lambda: run(args, out), prog=PROG)


if __name__ == "__main__":
    raise SystemExit(main())
