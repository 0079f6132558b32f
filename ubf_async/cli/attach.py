"""What a tool attaching to a running robot from another process does around its own work
(``python -m ubf_async.record``, ``python -m ubf_async.liveview``): its flags (``--duration``,
``--name``, ``--wait-for-robot-s``), a session that has reached the robot and stamps on the
robot's clock, and running until stopped."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
from collections.abc import AsyncIterator

from ubf_async.cli.args import connection_options
from ubf_async.clocks import follow
from ubf_async.runtime.bus import DEFAULT_ATTACH_TIMEOUT_S, Bus, wait_for_robot


def add_attach_arguments(parser: argparse.ArgumentParser, *, name: str, who: str) -> None:
    """``--duration S``, ``--name`` (default ``name``; ``who`` says whose name it is) and
    ``--wait-for-robot-s S``."""
    parser.add_argument("--duration", type=float, default=None, metavar="S",
                        help="stop after S wall-clock seconds (default: until Ctrl-C/SIGTERM)")
    parser.add_argument("--name", default=name, help=f"{who}'s component name on the robot")
    parser.add_argument("--wait-for-robot-s", type=float, default=DEFAULT_ATTACH_TIMEOUT_S,
                        metavar="S", help="with --connect: how long to wait for the robot")


@contextlib.asynccontextmanager
async def attached_bus(args: argparse.Namespace) -> AsyncIterator[Bus]:
    """A bus on the connection flags that has reached the robot (:func:`wait_for_robot`) and
    stamps on its clock (:func:`~ubf_async.clocks.follow.follow_robot_clock`); closed on
    exit."""
    bus = await Bus.open(connection_options(args))
    try:
        await wait_for_robot(bus, timeout_s=args.wait_for_robot_s)
        await follow.follow_robot_clock(bus, mode="auto")
        yield bus
    finally:
        await bus.aclose()


async def run_until_stopped(duration_s: float | None) -> None:
    """Return after ``duration_s`` wall seconds; with ``None`` only a cancellation (the first
    Ctrl-C or SIGTERM, through :func:`~ubf_async.cli.run.run_main`) ends it."""
    if duration_s is None:
        await asyncio.Event().wait()
    else:
        await asyncio.sleep(duration_s)
