"""``python -m ubf_async.monitor`` (``ubf-monitor``): the behaviour tree of a running robot,
live in a browser, served from another process. The monitor itself is
:mod:`ubf_async.services.monitor`, which ``launch --monitor`` runs in the robot's process."""

from __future__ import annotations

import argparse
import logging
from collections.abc import Callable, Sequence
from typing import Any

from ubf_async import extras
from ubf_async.cli.args import HelpFormatter, add_bind_host_argument, add_connection_arguments
from ubf_async.cli.attach import add_attach_arguments, attached_bus, serve_until_stopped
from ubf_async.cli.run import run_main
from ubf_async.net.options import DEFAULT_LISTEN
from ubf_async.services.monitor import DEFAULT_HOST, DEFAULT_PORT, MonitorServer

__all__ = ["PROG", "add_host_argument", "build_parser", "main", "serve"]

PROG = "python -m ubf_async.monitor"


def add_host_argument(parser: Any) -> None:
    add_bind_host_argument(parser, "--monitor-host", default=DEFAULT_HOST,
                           server="the tree monitor's page")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG, formatter_class=HelpFormatter,
        description="Serve the behaviour tree of a running robot live to a browser "
                    "(docs/monitor.md), from another process: open the printed http:// "
                    "address. The page draws the tree with each node's last vote, the winners "
                    "of the drive command, each source's age and a strip of the last 30 s of "
                    "winners to scrub through; from it an operator changes an arbiter, a "
                    "child's priority or weight, or loads a new tree — through this process's "
                    "identity in secure mode. A replay (python -m ubf_async.replay) shows the "
                    "same way. Ctrl-C or SIGTERM stops it.")
    add_connection_arguments(parser, default_connect=[DEFAULT_LISTEN])
    parser.add_argument("--port", type=int, default=DEFAULT_PORT,
                        help="the page's HTTP port (0: any free port)")
    add_host_argument(parser)
    parser.add_argument("--read-only", action="store_true",
                        help="refuse every change from the page (watching only)")
    add_attach_arguments(parser, name="monitor", who="the monitor")
    return parser


async def serve(args: argparse.Namespace, *,
                ready: Callable[[MonitorServer], None] | None = None) -> int:
    extras.require("monitor", "aiohttp", who=PROG)  # before waiting for a robot
    # Not on the robot's clock: the monitor stamps nothing a robot's rule reads (a tree
    # request is not judged by its stamp), and a replay it listens for says its clock only
    # once it has a subscriber.
    async with attached_bus(args, follow_clock=False) as bus:
        server = MonitorServer(
            bus=bus, port=args.port, host=args.monitor_host, name=args.name,
            allow_changes=not args.read_only,
            refusal=f"{PROG} was started with --read-only")
        return await serve_until_stopped(
            server, duration_s=args.duration, ready=ready,
            started=lambda s: f"{PROG}: robot {bus.robot!r}'s tree live on {s.url}")


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level="WARNING", format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    return run_main(lambda: serve(args), prog=PROG)


if __name__ == "__main__":
    raise SystemExit(main())
