"""The inspector's program: it opens a session that reaches the robot, runs the verb asked for,
and returns its exit status; ``main`` is ``python -m ubf_async.inspector`` and the
``ubf-inspect`` console script."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import TextIO

from ubf_async.cli.args import connection_options
from ubf_async.cli.attach import wait_for_robot
from ubf_async.cli.run import run_main
from ubf_async.errors import UbfError
from ubf_async.runtime.bus import Bus
from ubf_async.tools.inspector import (
    common,
    conform,
    graph,
    parser,
    pub,
    samples,
    schemas,
    state,
    tree,
)

__all__ = ["COMMANDS", "OFFLINE", "main", "open_bus", "run"]


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


COMMANDS = {"robots": graph.cmd_robots, "components": graph.cmd_components,
            "keys": graph.cmd_keys, "echo": samples.cmd_echo, "state": state.cmd_state,
            "tree": tree.cmd_tree, "hz": samples.cmd_rate, "bw": samples.cmd_rate,
            "info": graph.cmd_info, "pub": pub.cmd_pub, "conform": conform.cmd_conform}


OFFLINE = {"schemas": schemas.cmd_schemas}
"""Commands that need no robot (no session is opened)."""


async def run(args: argparse.Namespace, out: TextIO = sys.stdout) -> int:
    offline = OFFLINE.get(args.command)
    if offline is not None:
        return offline(args, out)
    try:
        bus = await open_bus(args)
    except (UbfError, ConnectionError) as exc:
        common.say_error(exc)
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
    args = parser.build_parser().parse_args(argv)
    out = sys.stdout  # itself, not run_main's guarded stream: `... | head` ends the command
    return run_main(lambda: run(args, out), prog=parser.PROG)
