"""``pub``: publish a message on a key, checked first exactly as the robot checks it, once or at
a rate until stopped."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import time
from collections.abc import Iterator
from typing import Any, TextIO

import yaml

from ubf_async.cli.run import STOP_SIGNALS
from ubf_async.clocks import follow
from ubf_async.runtime.bus import Bus
from ubf_async.tools.inspector import common
from ubf_async.wire import topics
from ubf_async.wire.protocol import encode

__all__ = ["add_pub_parser", "cmd_pub"]


def add_pub_parser(sub: Any, connection: argparse.ArgumentParser) -> None:
    """``pub``: publish a message on a key."""
    pub = sub.add_parser(
        "pub", parents=[connection], help="publish a message on a key, checked first",
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


async def cmd_pub(bus: Bus, args: argparse.Namespace, out: TextIO) -> int:
    try:
        key = common.resolve_key(bus.keys, args.key)
        if "*" in key:
            raise ValueError(f"{args.key}: pub needs one key, not a key expression")
        data = yaml.safe_load(args.data)
        if not isinstance(data, dict):
            raise ValueError(f"DATA must be a map of the message's fields, got {args.data!r}")
        schema = args.schema or common.expected_schema(bus.keys, key)
        if schema is None:
            raise ValueError(f"{key}: no declared topic covers this key; give --schema NAME")
        required = common.expected_schema(bus.keys, key)
        if required is not None and schema != required:
            raise ValueError(f"{key} takes schema {required!r}, not {schema!r}")
        encode(schema, data, stamp_ns=0, seq=1)  # the robot's checks, before anything is sent
        fields = topic.fields if (topic := topics.BY_SCHEMA.get(schema)) else ()
        unknown = sorted(map(str, set(data) - set(fields))) if fields else []
        if unknown:  # the robot ignores unknown fields: a typo would go unnoticed
            raise ValueError(f"{schema} has no field(s) {', '.join(unknown)} (the robot would "
                             f"ignore them); its fields: {', '.join(fields)}")
    except (ValueError, yaml.YAMLError) as exc:  # ProtocolError is a ValueError
        common.say_error(f"refused, nothing sent: {exc}")
        return 2
    if args.rate is not None and not args.rate > 0:
        common.say_error("--rate must be > 0")
        return 2
    if args.count is not None and args.count < 1:
        common.say_error("--count must be at least 1")
        return 2
    count = args.count if args.count is not None else (None if args.rate else 1)
    await follow.follow_robot_clock(bus, mode="auto")
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
