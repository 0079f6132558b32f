"""What a tool attaching to a running robot from another process does around its own work
(``python -m ubf_async.record``, ``python -m ubf_async.liveview``): its flags (``--duration``,
``--name``, ``--wait-for-robot-s``), waiting for the robot (:func:`wait_for_robot`), a session
that has reached the robot and stamps on the robot's clock, and running until stopped."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
from collections.abc import AsyncIterator, Callable
from typing import Protocol, TypeVar

from ubf_async.cli.args import connection_options
from ubf_async.clocks import follow
from ubf_async.errors import NoRobotError
from ubf_async.net.options import START_ROBOT_HINT, refused_error
from ubf_async.runtime.bus import Bus
from ubf_async.wire.keys import ROOT

__all__ = ["DEFAULT_ATTACH_TIMEOUT_S", "Served", "add_attach_arguments", "attached_bus",
           "run_until_stopped", "serve_until_stopped", "wait_for_robot"]

DEFAULT_ATTACH_TIMEOUT_S = 10.0


def add_attach_arguments(parser: argparse.ArgumentParser, *, name: str, who: str) -> None:
    """``--duration S``, ``--name`` (default ``name``; ``who`` says whose name it is) and
    ``--wait-for-robot-s S``."""
    parser.add_argument("--duration", type=float, default=None, metavar="S",
                        help="stop after S wall-clock seconds (default: until Ctrl-C/SIGTERM)")
    parser.add_argument("--name", default=name, help=f"{who}'s component name on the robot")
    parser.add_argument("--wait-for-robot-s", type=float, default=DEFAULT_ATTACH_TIMEOUT_S,
                        metavar="S", help="with --connect: how long to wait for the robot")


async def wait_for_robot(bus: Bus, *, timeout_s: float = DEFAULT_ATTACH_TIMEOUT_S,
                         any_robot: bool = False) -> None:
    """For a process attaching to a running robot: wait until the session reaches another
    zenoh node and one of the robot's components is alive there (its liveliness token
    ``ubf/<robot>/alive/*``). Raises :class:`NoRobotError` after ``timeout_s``, saying whether
    nothing answered at the endpoints or the robot there has another name, or
    :class:`RefusedError` when something listens there but never let the session in.

    Returns at once for a session that only listens (in ``peer`` mode without ``connect``
    endpoints others come to it). Call it right after :meth:`Bus.open`, before starting
    anything. ``any_robot``: any robot's component will do (a tool looking at a fleet).

    It asks (a liveliness query) once, and then again each time a component's heartbeat
    arrives (every component beats every half second): it waits on that event, not on a timer.
    Not on a liveliness subscriber: with zenoh 1.10 a client's liveliness queries made while
    such a subscriber is declared, or just after, sometimes find nothing (measured: an
    inspector listing no component in 2-3 runs of 30), and a tool's next step is such a
    query."""
    options = bus.options
    if not options.connect and options.mode != "client":
        return
    where = " ".join(options.connect) or "(the configured router)"
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout_s
    alive = f"{ROOT}/*/alive/*" if any_robot else bus.keys.all_alive
    beat = asyncio.Event()
    heartbeats = bus.subscribe(f"{ROOT}/*/heartbeat/*" if any_robot else bus.keys.all_heartbeats,
                               lambda key, payload, received_ns: beat.set())
    reached = False
    try:
        while True:
            beat.clear()
            reached = reached or bus.reached_peers()
            if reached and await bus.alive_tokens(alive, timeout_s=1.0):
                return
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(beat.wait(), deadline - loop.time())
            if loop.time() >= deadline:
                break
            reached = True  # a heartbeat came: another node is there
    finally:
        heartbeats.close()
    reached = reached or bus.reached_peers()
    if not reached:
        refused = await asyncio.to_thread(refused_error, options)
        if refused is not None:
            raise refused
        raise NoRobotError(f"no robot to connect to: nothing answered at {where} within "
                           f"{timeout_s:g}s ({START_ROBOT_HINT})")
    seen = sorted({key.split("/")[1] for key in await bus.alive_tokens(
        f"{ROOT}/*/alive/*", timeout_s=1.0)} - {bus.robot})
    other = f"; robots there: {', '.join(seen)} (check --robot)" if seen else ""
    raise NoRobotError(f"no robot {bus.robot!r} answered at {where} within {timeout_s:g}s: "
                       f"a zenoh node is there, but none of the robot's components is alive"
                       f"{other}")


@contextlib.asynccontextmanager
async def attached_bus(args: argparse.Namespace, *,
                       follow_clock: bool = True) -> AsyncIterator[Bus]:
    """A bus on the connection flags that has reached the robot (:func:`wait_for_robot`) and
    stamps on its clock (:func:`~ubf_async.clocks.follow.follow_robot_clock`; ``follow_clock``
    ``False``: this host's, for a tool that stamps nothing a robot's rule reads); closed on
    exit."""
    bus = await Bus.open(connection_options(args))
    try:
        await wait_for_robot(bus, timeout_s=args.wait_for_robot_s)
        if follow_clock:
            await follow.follow_robot_clock(bus, mode="auto")
        yield bus
    finally:
        await bus.aclose()


class Served(Protocol):
    """A server a tool runs on the robot's bus (the live view, the tree monitor)."""

    async def start(self) -> None: ...
    async def aclose(self) -> None: ...


S = TypeVar("S", bound=Served)


async def serve_until_stopped(server: S, *, duration_s: float | None,
                              started: Callable[[S], str],
                              ready: Callable[[S], None] | None = None,
                              closed: Callable[[S], str] | None = None) -> int:
    """Start ``server``, print what ``started`` says of it, hand it to ``ready`` (a test),
    run until stopped (:func:`run_until_stopped`), close it and print what ``closed`` says.
    Exit status 0."""
    await server.start()
    try:
        print(started(server), flush=True)
        if ready is not None:
            ready(server)
        await run_until_stopped(duration_s)
        return 0
    finally:
        await server.aclose()
        if closed is not None:
            print(closed(server), flush=True)


async def run_until_stopped(duration_s: float | None) -> None:
    """Return after ``duration_s`` wall seconds; with ``None`` only a cancellation (the first
    Ctrl-C or SIGTERM, through :func:`~ubf_async.cli.run.run_main`) ends it."""
    if duration_s is None:
        await asyncio.Event().wait()
    else:
        await asyncio.sleep(duration_s)
