"""A zenoh router for a fleet: ``python -m ubf_async.router``.

A robot on its own needs no router: its launch listens, and tools on the same host connect to
it as peers. A **fleet** — several robots, their devices and tools, possibly on several hosts —
meets at a router instead: every process joins it in ``client`` mode
(``--mode client --connect <the endpoint this prints>``), and each robot keeps to its own keys
``ubf/<robot>/…``. Routers on different hosts connect to each other (``--connect`` here), so a
robot on one host reaches a tool or a robot on another through them (``docs/fleet.md``).

This runs zenoh-python's own router (a session in ``router`` mode) with the shared connection
flags: ``--listen`` (default ``tcp/127.0.0.1:7447``; ``tcp/0.0.0.0:7447`` to serve other
hosts), ``--connect`` for other routers, a JSON5 ``--config`` under them, multicast scouting off
unless asked. It prints which robots are alive on it (their components' liveliness tokens) as
they come and go.

Sessions made by :class:`~ubf_async.net.options.ConnectionOptions` retry a lost connection every
:data:`~ubf_async.net.options.RECONNECT_RETRY` (at most 1 s apart, where zenoh's default backs off
to 4 s), so a restarted router has every client back within about a second of its return. While a
client is disconnected, what it publishes is lost (zenoh keeps no queue for an absent
router) and what it subscribes to does not arrive: a robot's motors stop on their watchdog, its
controller sees its sensors go stale, exactly as with a dead sensor.
"""

from __future__ import annotations

import argparse
import asyncio
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TextIO

from ubf_async.cli.args import HelpFormatter, add_event_loop_help, add_secure_arguments
from ubf_async.cli.run import run_main
from ubf_async.net.options import ConnectionOptions, load_zenoh_config, over_tls
from ubf_async.net.secure import ROUTER
from ubf_async.runtime.bus import Bus
from ubf_async.wire.keys import ROOT

__all__ = ["DEFAULT_LISTEN", "PROG", "REPORT_EVERY_S", "FleetRoster", "build_parser", "main",
           "router_options", "serve"]

PROG = "python -m ubf_async.router"
DEFAULT_LISTEN = "tcp/127.0.0.1:7447"
REPORT_EVERY_S = 1.0
"""Changes in the robots alive are printed at most this often (a robot starts many components
at once)."""


class FleetRoster:
    """Which components of which robots are alive, from their liveliness tokens
    ``ubf/<robot>/alive/<component>``."""

    def __init__(self) -> None:
        self.components: dict[str, set[str]] = {}
        self.changed = False

    def on_token(self, key: str, alive: bool) -> None:
        parts = key.split("/", 3)
        if len(parts) != 4 or parts[0] != ROOT or parts[2] != "alive":
            return
        robot, component = parts[1], parts[3]
        members = self.components.setdefault(robot, set())
        before = len(members)
        if alive:
            members.add(component)
        else:
            members.discard(component)
        if not members:
            del self.components[robot]
        self.changed = self.changed or len(members) != before

    def line(self) -> str:
        if not self.components:
            return "no robot alive"
        robots = ", ".join(f"{robot} ({len(members)} component{'s' * (len(members) != 1)})"
                           for robot, members in sorted(self.components.items()))
        return f"robots alive: {robots}"


def build_parser() -> argparse.ArgumentParser:
    from ubf_async import __version__

    parser = argparse.ArgumentParser(
        prog=PROG, formatter_class=HelpFormatter,
        description=(
            "Run a zenoh router for a fleet of robots (docs/fleet.md). Robots, devices and "
            "tools join it with --mode client --connect <endpoint>; routers on other hosts "
            "join it with --connect. Prints the robots alive on it as they come and go."),
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    group = parser.add_argument_group("connection")
    group.add_argument("--listen", "-l", action="append", default=None, metavar="ENDPOINT",
                       help=f"endpoint to listen on (repeatable); default: {DEFAULT_LISTEN} "
                            "unless the --config file sets listen endpoints; "
                            "tcp/0.0.0.0:7447 serves other hosts")
    group.add_argument("--connect", "-e", action="append", default=[], metavar="ENDPOINT",
                       help="another router to connect to, e.g. tcp/10.0.0.2:7447 "
                            "(repeatable)")
    group.add_argument("--config", type=Path, default=None, metavar="FILE",
                       help="zenoh JSON5 configuration file (the flags given override it)")
    group.add_argument("--multicast-scouting", action="store_true",
                       help="also discover routers and peers by UDP multicast (off by default)")
    add_secure_arguments(
        group, secure_help="secure mode: mutual TLS (tls/ endpoints only) with a fleet's set-up "
                           "(`python -m ubf_async.secure init DIR --fleet-file FLEET.yaml`); "
                           "the router holds its access control (docs/security.md)",
        identity_help="with --secure: the router's identity (default: router)")
    parser.add_argument("--duration", type=float, default=None, metavar="S",
                        help="stop after S seconds (default: until Ctrl-C)")
    parser.add_argument("--quiet", action="store_true",
                        help="print only the endpoints, not the robots coming and going")
    add_event_loop_help(parser)
    return parser


def router_options(args: argparse.Namespace) -> ConnectionOptions:
    """The router's :class:`ConnectionOptions`: ``router`` mode whatever the file says, the
    flags over the file, the default endpoint when neither sets one."""
    listen = args.listen
    if listen is None and args.config is not None:
        conf = load_zenoh_config(args.config)
        if conf.get_json("listen/endpoints") != type(conf)().get_json("listen/endpoints"):
            listen = []  # the file's own
    if listen is None:
        listen = [over_tls(DEFAULT_LISTEN) if args.secure else DEFAULT_LISTEN]
    return ConnectionOptions(mode="router", listen=list(listen), connect=list(args.connect),
                             config=args.config, multicast_scouting=args.multicast_scouting,
                             secure=args.secure,
                             identity=(args.identity or ROUTER) if args.secure else args.identity)


async def serve(args: argparse.Namespace, out: TextIO) -> int:
    options = router_options(args)
    bus = await Bus.open(options)
    try:
        endpoints = " ".join(bus.options.listen) or "(the --config file's endpoints)"
        join = bus.options.listen[0] if bus.options.listen else "<endpoint>"
        print(f"router: listening on {endpoints}", file=out)
        secure = (f" --secure {options.secure} --identity NAME"
                  if options.secure is not None else "")
        print(f"  robots, devices and tools join with: --mode client --connect {join}{secure}",
              file=out, flush=True)
        roster = FleetRoster()
        watch = bus.watch_liveliness(f"{ROOT}/*/alive/*", roster.on_token)
        deadline = None if args.duration is None else time.monotonic() + args.duration
        try:
            while deadline is None or time.monotonic() < deadline:
                pause = REPORT_EVERY_S if deadline is None else min(
                    REPORT_EVERY_S, max(0.0, deadline - time.monotonic()))
                await asyncio.sleep(pause)
                if roster.changed and not args.quiet:
                    roster.changed = False
                    print(f"router: {roster.line()}", file=out, flush=True)
        finally:
            watch.close()
    finally:
        await bus.aclose()
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return run_main(lambda: serve(args, sys.stdout), prog=PROG)


if __name__ == "__main__":
    raise SystemExit(main())
