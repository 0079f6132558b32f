"""``python -m ubf_async.launch`` — run a robot: bus, state aggregator, UBF controller.

Starts a zenoh session (listening on a loopback endpoint by default, printed at start so
other processes can attach with ``--connect``), the state aggregator, the controller with
the seek-the-pink-ball behaviour tree, and a health monitor; prints a one-line live status
until Ctrl-C, SIGTERM or ``--duration`` elapses, then shuts everything down cleanly.
"""

from __future__ import annotations

import argparse
import asyncio
import importlib
import logging
import random
import sys
import time
from collections.abc import Sequence
from types import ModuleType
from typing import Any, TextIO

from ubf_async.aggregator import StateAggregator
from ubf_async.behaviors import seek_pink_ball
from ubf_async.bus import (
    DEFAULT_LISTEN,
    Bus,
    HelpFormatter,
    add_connection_arguments,
    connection_options,
    follow_sim_clock,
)
from ubf_async.cli import run_main
from ubf_async.clock import Clock, SimClock, WallClock
from ubf_async.component import Component, HealthMonitor
from ubf_async.controller import Controller, TickMode
from ubf_async.remote import RemoteBehaviors, remote_spec

log = logging.getLogger("ubf_async.launch")


DEFAULT_SIMULATOR = "components.sim.runner"


def build_parser(simulator: ModuleType | None = None) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m ubf_async.launch",
        description=(
            "Run a UBF robot: zenoh session, state aggregator, controller (seek the pink ball), "
            "by default a simulated Mini-WHEGS with its devices, and a live status line. Other "
            "processes attach over zenoh with --connect <the endpoint printed at start> and the "
            "same --robot."
        ),
        formatter_class=HelpFormatter,
    )
    add_connection_arguments(parser, default_listen=[DEFAULT_LISTEN])
    ctl = parser.add_argument_group("controller")
    ctl.add_argument("--rate-hz", type=float, default=50.0,
                     help="tick rate in periodic mode")
    ctl.add_argument("--tick", dest="tick_mode", choices=[m.value for m in TickMode],
                     default=TickMode.PERIODIC.value,
                     help="periodic: own clock; sync: wait for each camera sample (the "
                          "thesis's loop); event: tick on each sample of --trigger")
    ctl.add_argument("--trigger", default=None, metavar="SOURCE",
                     help="source that triggers ticks in --tick event, e.g. range/front")
    ctl.add_argument("--reflex", action="append", default=None, metavar="PREFIX",
                     help="in periodic mode, also tick at once on each sample of sources "
                          "starting with PREFIX (repeatable; default: range/ — the IR "
                          "finders; --reflex '' for none)")
    ctl.add_argument("--camera-source", default="camera/front", metavar="SOURCE",
                     help="camera source the behaviours and sync mode read")
    ctl.add_argument("--remote", type=remote_spec, action="append", default=[],
                     metavar="[COMPOSITE/]NAME=PRIORITY[:WEIGHT]",
                     help="place remote behaviour NAME (docs/protocol.md, 'Remote behaviours') "
                          "at PRIORITY[:WEIGHT] in its composite, overriding what its votes ask "
                          "for (repeatable); other remote behaviours get what they ask for")
    ctl.add_argument("--search-period-s", type=float, default=None,
                     help="search behaviour's counter: how often it draws a new direction "
                          "(default: the scenario's, else 4)")
    world = parser.add_argument_group("where the devices come from")
    world.add_argument("--no-sim", action="store_true",
                       help="no simulator: run only the controller and wait for devices to "
                            "attach over zenoh")
    world.add_argument("--sim-time", action="store_true",
                       help="with --no-sim: follow the simulation time published on "
                            "ubf/<robot>/clock by a simulator in another process")
    world.add_argument("--simulator", default=DEFAULT_SIMULATOR, metavar="MODULE",
                       help="module that provides the simulated robot")
    if simulator is not None:
        simulator.add_arguments(parser)
    run = parser.add_argument_group("run")
    run.add_argument("--duration", type=float, default=None, metavar="S",
                     help="stop after S seconds (simulated seconds when simulating; default: "
                          "the scenario's duration if --scenario is given, else until Ctrl-C)")
    run.add_argument("--status-period-s", type=float, default=0.5,
                     help="how often (wall seconds) the status line refreshes")
    run.add_argument("--quiet", action="store_true", help="no status line")
    run.add_argument("--log-level", default="WARNING",
                     choices=["DEBUG", "INFO", "WARNING", "ERROR"])
    return parser


def load_simulator(argv: Sequence[str] | None) -> ModuleType | None:
    """Import the simulator module named by ``--simulator`` unless ``--no-sim`` is given, so
    its options join ``--help``. The framework itself never imports a simulator statically."""
    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--no-sim", action="store_true")
    pre.add_argument("--simulator", default=DEFAULT_SIMULATOR)
    known, _ = pre.parse_known_args(argv)
    if known.no_sim:
        return None
    try:
        return importlib.import_module(known.simulator)
    except ImportError as exc:
        raise SystemExit(f"error: --simulator {known.simulator}: {exc}") from None


def format_status(
    robot: str, elapsed_s: float, controller: Controller, aggregator: StateAggregator,
    health: HealthMonitor,
) -> str:
    stats = controller.stats
    rate = stats.rate_hz()
    parts = [f"[{robot}] {elapsed_s:6.1f}s",
             f"tick {rate:5.1f}Hz" if rate else "tick   --  ",
             f"overruns {stats.overruns}"]
    sources = aggregator.sources()
    if sources:
        parts.append(" ".join(
            f"{s.source} {s.age_s * 1e3:.0f}ms{' STALE' if s.stale else ''}" for s in sources
        ))
    else:
        parts.append(f"no sensors yet (waiting on ubf/{robot}/sensor/*/*)")
    last = controller.last_action
    if last is not None:
        winners = ",".join(controller.last_trace.winning_leaves()) if controller.last_trace else ""
        parts.append(f"drive {last.speed:+4.0f}/{last.turn:+4.0f} ({winners or 'stop'})")
    bad = sum(aggregator.malformed.values())
    if bad:
        parts.append(f"rejected {bad}")
    unhealthy = health.unhealthy()
    if unhealthy:
        parts.append("UNHEALTHY " + ",".join(unhealthy))
    return " | ".join(parts)


async def run_robot(
    args: argparse.Namespace, simulator: ModuleType | None, out: TextIO = sys.stdout
) -> int:
    options = connection_options(args)
    clock: Clock = SimClock() if simulator is not None or args.sim_time else WallClock()
    bus = await Bus.open(options, clock=clock)
    components: list[Component] = []
    health = HealthMonitor(bus)
    sim_run = None
    controller: Controller | None = None
    try:
        endpoints = " ".join(options.listen) or "(not listening)"
        print(f"ubf_async: robot {options.robot!r} on zenoh, listening on {endpoints}", file=out)
        if options.listen:
            print(f"  attach with: --connect {options.listen[0]} --robot {options.robot}",
                  file=out)
        if simulator is not None:
            assert isinstance(clock, SimClock)
            sim_run = simulator.SimulationRun(bus=bus, clock=clock, args=args)
            print(f"  {sim_run.describe()}", file=out)
        elif isinstance(clock, SimClock):
            follow_sim_clock(bus, clock, {})
            print(f"  no simulator here: following the simulation time on {bus.keys.clock}",
                  file=out)
        else:
            print("  no simulator: waiting for devices to attach over zenoh", file=out)
        search_period_s = args.search_period_s or (sim_run.search_period_s if sim_run else 4.0)
        aggregator = StateAggregator(bus=bus)
        # The search behaviour draws its directions from the run's seed, so a simulated run
        # is repeatable.
        rng = random.Random(sim_run.seed) if sim_run is not None else random.Random()
        root = seek_pink_ball(source=args.camera_source, search_period_s=search_period_s,
                              rng=rng)
        controller = Controller(
            bus=bus, aggregator=aggregator, root=root, rate_hz=args.rate_hz,
            mode=args.tick_mode, camera_source=args.camera_source, trigger=args.trigger,
            reflex_sources=tuple(p for p in (args.reflex or ["range/"]) if p),
        )
        remotes = RemoteBehaviors(bus=bus, root=root, config=dict(args.remote))
        components += [aggregator, controller, remotes]
        if sim_run is not None:
            components += sim_run.components()
        health.start()
        for component in components:
            await component.start()
        if sim_run is not None:
            sim_run.start(controller)
        print(f"  controller: {args.tick_mode} at {args.rate_hz:g} Hz, tree:", file=out)
        for line in root.render_tree().splitlines():
            print(f"    {line}", file=out)
        out.flush()
        await _run_until_done(args, out, options.robot, controller, aggregator, health, sim_run)
        return 0
    finally:
        if not args.quiet and out.isatty():
            out.write("\n")
        if sim_run is not None and controller is not None:
            await sim_run.finish(controller, out)
        for component in reversed(components):
            await component.aclose()
        health.close()
        await bus.aclose()
        print("ubf_async: stopped", file=out)
        out.flush()


async def _run_until_done(
    args: argparse.Namespace, out: TextIO, robot: str, controller: Controller,
    aggregator: StateAggregator, health: HealthMonitor, sim_run: Any,
) -> None:
    """Print the status line until the run's duration has passed (forever without one)."""
    wall_start = time.monotonic()
    duration = sim_run.duration_s if sim_run is not None else args.duration

    def elapsed() -> float:
        return sim_run.elapsed_s() if sim_run is not None else time.monotonic() - wall_start

    async def report() -> None:
        interactive = out.isatty()
        while True:
            await asyncio.sleep(args.status_period_s)
            line = format_status(robot, elapsed(), controller, aggregator, health)
            if sim_run is not None and (suffix := sim_run.status_suffix()):
                line += f" | {suffix}"
            if interactive:
                out.write("\r\x1b[2K" + line[:200])
            else:
                out.write(line + "\n")
            out.flush()

    if duration is None:
        await (asyncio.Event().wait() if args.quiet else report())
        return
    reporter = None if args.quiet else asyncio.create_task(report())
    try:
        # A simulated run ends the moment simulated time reaches its duration.
        await (sim_run.until_elapsed(duration) if sim_run is not None
               else asyncio.sleep(duration))
    finally:
        if reporter is not None:
            reporter.cancel()
            await asyncio.gather(reporter, return_exceptions=True)


def main(argv: Sequence[str] | None = None) -> int:
    simulator = load_simulator(argv)
    parser = build_parser(simulator)
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=args.log_level, format="%(asctime)s %(levelname)s %(name)s: %(message)s"
    )
    if args.sim_time and not args.no_sim:
        parser.error("--sim-time only makes sense with --no-sim")
    if args.tick_mode == TickMode.EVENT and not args.trigger:
        parser.error("--tick event needs --trigger SOURCE")

    return run_main(lambda: run_robot(args, simulator), prog="python -m ubf_async.launch")


if __name__ == "__main__":
    raise SystemExit(main())
