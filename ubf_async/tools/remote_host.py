"""A remote behaviour's process: :func:`remote_parser` (the shared connection flags and the
remote-behaviour flags) and :func:`run_remote_behavior` make a command-line program of any
:class:`~ubf_async.core.behavior.Behavior` (``examples/teleop_override.py``,
``examples/avoid_obstacles.py``). The component that runs it,
:class:`~ubf_async.services.remote.RemoteBehaviorHost`, and the robot's side are
:mod:`ubf_async.services.remote`."""

from __future__ import annotations

import argparse
import asyncio
import logging
import sys
import time
from collections.abc import Callable
from typing import TextIO

from ubf_async.access.setup import rights
from ubf_async.cli.args import add_connection_arguments, connection_options
from ubf_async.cli.attach import DEFAULT_ATTACH_TIMEOUT_S, wait_for_robot
from ubf_async.cli.run import run_main
from ubf_async.clocks import follow
from ubf_async.clocks.clock import Clock, WallClock
from ubf_async.core.behavior import Behavior
from ubf_async.errors import ConfigurationError
from ubf_async.net.options import DEFAULT_LISTEN
from ubf_async.runtime import refusals, timekeepers
from ubf_async.runtime.bus import Bus
from ubf_async.runtime.component import ensure_name_free
from ubf_async.services.remote import DEFAULT_TTL_S, RemoteBehaviorHost, vote_key
from ubf_async.wire.keys import Keys

__all__ = ["choose_clock", "host_remote_behavior", "remote_parser", "run_remote_behavior"]


def remote_parser(
    *,
    prog: str | None = None,
    description: str,
    name: str,
    composite: str = "seek_pink_ball",
    priority: int = 0,
    weight: float = 1.0,
    rate_hz: float = 20.0,
    ttl_s: float = DEFAULT_TTL_S,
) -> argparse.ArgumentParser:
    """A parser with the shared connection flags and the remote-behaviour flags; add your
    behaviour's own options to it, then call :func:`run_remote_behavior`."""
    parser = argparse.ArgumentParser(
        prog=prog, description=description,
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    add_connection_arguments(parser, default_connect=[DEFAULT_LISTEN])
    parser.epilog = (f"Without --connect or --listen it connects to {DEFAULT_LISTEN}, where "
                     "`python -m ubf_async.launch` listens by default.")
    group = parser.add_argument_group("remote behaviour (see docs/protocol.md)")
    group.add_argument("--name", default=name,
                       help="behaviour name: its liveliness token is ubf/<robot>/alive/<name>")
    group.add_argument("--composite", default=composite,
                       help="the composite of the robot's tree to join")
    group.add_argument("--priority", type=int, default=priority,
                       help="priority requested in the composite (the robot's configuration "
                            "may override it)")
    group.add_argument("--weight", type=float, default=weight, help="weight requested")
    group.add_argument("--rate-hz", type=float, default=rate_hz,
                       help="how often the behaviour runs and votes")
    group.add_argument("--trigger", default=None, metavar="SOURCE",
                       help="vote on every new sample of SOURCE (e.g. range/front) instead of "
                            "at --rate-hz")
    group.add_argument("--ttl-s", type=float, default=ttl_s,
                       help="how long each vote holds on the robot")
    group.add_argument("--clock", choices=("auto", "wall", "sim"), default="auto",
                       help="robot clock: wall (CLOCK_MONOTONIC), sim (follow "
                            "ubf/<robot>/clock), auto (the one the robot says it runs on: "
                            "simulated time, or its host's clock, followed from another "
                            "host)")
    group.add_argument("--lockstep", action="store_true",
                       help="on a simulated robot: take part in the simulator's lockstep, so "
                            "every vote counts at the simulated instant it was made for and "
                            "a run is repeatable (docs/protocol.md, Lockstep)")
    group.add_argument("--wait-for-robot-s", type=float, default=DEFAULT_ATTACH_TIMEOUT_S,
                       metavar="S", help="how long to wait for the robot to answer before "
                                         "giving up")
    group.add_argument("--clock-wait-s", type=float, default=follow.DEFAULT_CLOCK_WAIT_S,
                       help="with --clock auto: how long to wait for the robot to say which "
                            "clock it runs on (a running robot does within a second) before "
                            "stamping with this host's clock")
    run = parser.add_argument_group("run")
    run.add_argument("--duration", type=float, default=None, metavar="S",
                     help="stop after S seconds (default: until Ctrl-C or SIGTERM)")
    run.add_argument("--status-period-s", type=float, default=1.0,
                     help="how often the status line is printed")
    run.add_argument("--quiet", action="store_true", help="no status line")
    run.add_argument("--log-level", default="WARNING",
                     choices=["DEBUG", "INFO", "WARNING", "ERROR"])
    return parser


async def choose_clock(bus: Bus, mode: follow.ClockMode, *,
                       wait_s: float = follow.DEFAULT_CLOCK_WAIT_S,
                       say: Callable[[str], None] | None = None) -> Clock:
    """The clock a remote process stamps with (``wall``, ``sim`` or ``auto``): the robot's,
    as :func:`ubf_async.clocks.follow.follow_robot_clock` finds it (``say``: its lines for the
    user). Sets ``bus.clock`` and returns it."""
    return await follow.follow_robot_clock(bus, mode=mode, wait_s=wait_s, say=say)


async def host_remote_behavior(
    behavior: Behavior, args: argparse.Namespace, out: TextIO = sys.stdout
) -> int:
    """Run ``behavior`` as a remote behaviour with the options of :func:`remote_parser`."""
    if args.name:
        behavior.name = args.name
    if getattr(args, "secure", None) is not None and getattr(args, "identity", None) is None:
        args.identity = behavior.name  # a remote slot's identity is the slot's name
    options = connection_options(args)
    # Before anything connects: what the robot's access control would drop without a word.
    keys, may = Keys(options.robot), rights(options)
    may.check("put", vote_key(keys, args.composite, behavior.name))
    may.check("put", keys.heartbeat(behavior.name))
    may.check("liveliness_token", keys.alive(behavior.name))
    bus = await Bus.open(options, clock=WallClock(), ordered=args.lockstep)
    host: RemoteBehaviorHost | None = None
    participant: timekeepers.LockstepParticipant | None = None
    refusals_watch: refusals.RefusalWatch | None = None

    def say(line: str) -> None:
        print(f"  {line}", file=out, flush=True)

    try:
        await wait_for_robot(bus, timeout_s=args.wait_for_robot_s)
        if args.lockstep and args.clock == "wall":
            raise ConfigurationError("--lockstep takes part in a simulated run: not with "
                                     "--clock wall")
        clock = await choose_clock(bus, args.clock, wait_s=args.clock_wait_s, say=say)
        host = RemoteBehaviorHost(
            bus=bus, behavior=behavior, composite=args.composite, rate_hz=args.rate_hz,
            trigger=args.trigger, ttl_s=args.ttl_s, priority=args.priority,
            weight=args.weight,
        )
        await ensure_name_free(bus, host.name, hint="start it with another --name")
        timing = f"on {args.trigger}" if args.trigger else f"at {args.rate_hz:g} Hz"
        print(f"remote behaviour {behavior.name!r} votes in {args.composite!r} of robot "
              f"{options.robot!r} {timing} (priority {args.priority}, weight {args.weight:g}, "
              f"ttl {args.ttl_s:g}s) on {host.key}", file=out)
        print(f"  clock: {clock.describe(options.robot)}"
              + (", in lockstep" if args.lockstep else ""), file=out)
        out.flush()
        # Before the first vote, so that the robot's first refusal is heard (on stderr).
        votes_key = host.key
        refusals_watch = refusals.RefusalWatch(bus, mine=lambda key: key == votes_key,
                                               who=behavior.name)
        refusals_watch.start()
        await host.start()
        if args.lockstep:
            participant = timekeepers.LockstepParticipant(bus=bus, participant=host.name)
            await participant.start()
        started = time.monotonic()
        last = 0.0
        while args.duration is None or time.monotonic() - started < args.duration:
            await asyncio.sleep(0.1)
            now = time.monotonic()
            if args.quiet or now - last < args.status_period_s:
                continue
            last = now
            mine = host.last_action.describe() if host.last_action else "abstain"
            robot = host.robot_action
            drive = (f"robot drive {robot.speed:+.0f}/{robot.turn:+.0f} "
                     f"({','.join(host.robot_winners) or 'stop'})" if robot else
                     "no drive command seen yet")
            refused = refusals_watch.refusing()
            why = (f" | REFUSED by the robot ({refused.reason}, {refused.count} so far)"
                   if refused is not None else "")
            print(f"[{behavior.name}] votes {host.votes}: {mine} | {drive}{why}", file=out)
            out.flush()
        return 0
    finally:
        if participant is not None:
            await participant.aclose()
        if host is not None:
            await host.aclose()
        if refusals_watch is not None:
            refusals_watch.close()
        await bus.aclose()


def run_remote_behavior(
    make_behavior: Callable[[argparse.Namespace], Behavior], args: argparse.Namespace
) -> int:
    """Entry point for a remote-behaviour program: logging, SIGTERM, asyncio, exit code."""
    logging.basicConfig(level=args.log_level,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    behavior = make_behavior(args)

    return run_main(lambda: host_remote_behavior(behavior, args), prog=sys.argv[0])
