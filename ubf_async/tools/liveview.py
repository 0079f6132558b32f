"""``python -m ubf_async.liveview`` (``ubf-liveview``): serve a running robot live to Foxglove
from another process. The live view itself (converters, the Foxglove server) is
:mod:`ubf_async.services.liveview`, which ``launch --foxglove`` runs in the robot's process."""

from __future__ import annotations

import argparse
import logging
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from ubf_async import extras
from ubf_async.cli.args import HelpFormatter, add_bind_host_argument, add_connection_arguments
from ubf_async.cli.attach import add_attach_arguments, attached_bus, serve_until_stopped
from ubf_async.cli.run import run_main
from ubf_async.net.options import DEFAULT_LISTEN
from ubf_async.services.liveview import (
    DEFAULT_HOST,
    DEFAULT_PORT,
    FoxgloveServer,
    layout_json,
)

__all__ = ["PROG", "add_host_argument", "build_parser", "main", "serve"]

PROG = "python -m ubf_async.liveview"


def add_host_argument(parser: Any) -> None:
    add_bind_host_argument(parser, "--foxglove-host", default=DEFAULT_HOST,
                           server="the Foxglove server")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog=PROG, formatter_class=HelpFormatter,
        description="Serve a running robot live to Foxglove (docs/liveview.md), from another "
                    "process: open ws://HOST:PORT in Foxglove and import "
                    "docs/foxglove-layout.json. Ctrl-C or SIGTERM stops it.")
    add_connection_arguments(parser, default_connect=[DEFAULT_LISTEN])
    parser.add_argument("--port", type=int, default=DEFAULT_PORT,
                        help="the Foxglove WebSocket server's port (0: any free port)")
    add_host_argument(parser)
    add_attach_arguments(parser, name="foxglove", who="the live view")
    parser.add_argument("--layout", type=Path, default=None, metavar="FILE",
                        help="write the Foxglove layout to FILE (- for stdout) and exit")
    return parser


async def serve(args: argparse.Namespace, *,
                ready: Callable[[FoxgloveServer], None] | None = None) -> int:
    extras.require("view", "foxglove", who=PROG)  # before waiting for a robot
    async with attached_bus(args) as bus:
        server = FoxgloveServer(bus=bus, port=args.port, host=args.foxglove_host,
                                name=args.name)
        return await serve_until_stopped(
            server, duration_s=args.duration, ready=ready,
            started=lambda s: f"{PROG}: robot {bus.robot!r} live on {s.url} (Foxglove: open "
                              f"connection → Foxglove WebSocket)",
            closed=lambda s: f"{PROG}: {s.stats.summary()}")


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.layout is not None:
        text = layout_json()
        if str(args.layout) == "-":
            print(text, end="")
        else:
            args.layout.write_text(text, encoding="utf-8")
        return 0
    logging.basicConfig(level="WARNING", format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    return run_main(lambda: serve(args), prog=PROG)


if __name__ == "__main__":
    raise SystemExit(main())
