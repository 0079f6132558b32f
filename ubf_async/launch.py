"""``python -m ubf_async.launch`` — run a robot: bus, state aggregator, UBF controller.

Starts a zenoh session (listening on a loopback endpoint by default, printed at start so
other processes can attach with ``--connect``), the state aggregator, the controller with
the seek-the-pink-ball behaviour tree, and a health monitor; prints a one-line live status
until Ctrl-C, SIGTERM or ``--duration`` elapses, then shuts everything down cleanly.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import signal
import sys
import time
from collections.abc import Sequence
from typing import TextIO

from components.sim.component import DEVICES, SimulatorComponent, simulated_devices
from components.sim.scenes import ball_in_view
from components.sim.world import World
from ubf_async.aggregator import StateAggregator
from ubf_async.behaviors import seek_pink_ball
from ubf_async.bus import (
    DEFAULT_LISTEN,
    Bus,
    add_connection_arguments,
    connection_options,
    follow_sim_clock,
)
from ubf_async.clock import Clock, SimClock, WallClock
from ubf_async.component import Component, HealthMonitor
from ubf_async.controller import Controller, TickMode

log = logging.getLogger("ubf_async.launch")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m ubf_async.launch",
        description=(
            "Run a UBF robot: zenoh session, state aggregator, controller (seek the pink ball) "
            "and a live status line. Other processes attach over zenoh with "
            "--connect <the endpoint printed at start> and the same --robot."
        ),
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
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
    ctl.add_argument("--camera-source", default="camera/front", metavar="SOURCE",
                     help="camera source the behaviours and sync mode read")
    ctl.add_argument("--search-period-s", type=float, default=4.0,
                     help="search behaviour's counter: how often it draws a new direction")
    sim = parser.add_argument_group("simulated robot")
    sim.add_argument("--no-sim", action="store_true",
                     help="run only the controller and wait for devices to attach over zenoh "
                          "(on wall-clock time)")
    sim.add_argument("--sim-time", action="store_true",
                     help="with --no-sim: follow the simulation time published on "
                          "ubf/<robot>/clock by a simulator in another process")
    sim.add_argument("--speed", type=float, default=1.0, metavar="K",
                     help="run the simulation K times faster than real time (every component, "
                          "camera latency included, follows the simulated clock)")
    sim.add_argument("--devices", default=",".join(DEVICES),
                     help="comma-separated simulated devices to start; others can attach later")
    sim.add_argument("--camera-latency-s", type=float, default=0.11,
                     help="capture latency of the simulated OV9655 camera")
    sim.add_argument("--seed", type=int, default=0, help="seed for every random source")
    run = parser.add_argument_group("run")
    run.add_argument("--duration", type=float, default=None, metavar="S",
                     help="stop after S seconds (default: run until Ctrl-C)")
    run.add_argument("--status-period-s", type=float, default=0.5,
                     help="how often the status line refreshes")
    run.add_argument("--quiet", action="store_true", help="no status line")
    run.add_argument("--log-level", default="WARNING",
                     choices=["DEBUG", "INFO", "WARNING", "ERROR"])
    return parser


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


def parse_devices(text: str) -> list[str]:
    devices = [d.strip() for d in text.split(",") if d.strip()]
    unknown = sorted(set(devices) - set(DEVICES))
    if unknown:
        raise SystemExit(f"error: --devices: unknown {unknown}; choose from {list(DEVICES)}")
    return devices


async def run_robot(args: argparse.Namespace, out: TextIO = sys.stdout) -> int:
    options = connection_options(args)
    devices = [] if args.no_sim else parse_devices(args.devices)
    clock: Clock = WallClock() if args.no_sim and not args.sim_time else SimClock()
    bus = await Bus.open(options, clock=clock)
    clock_errors: dict[str, int] = {}
    components: list[Component] = []
    simulator: SimulatorComponent | None = None
    health = HealthMonitor(bus)
    try:
        endpoints = " ".join(options.listen) or "(not listening)"
        print(f"ubf_async: robot {options.robot!r} on zenoh, listening on {endpoints}", file=out)
        if options.listen:
            print(f"  attach with: --connect {options.listen[0]} --robot {options.robot}",
                  file=out)
        aggregator = StateAggregator(bus=bus)
        root = seek_pink_ball(source=args.camera_source, search_period_s=args.search_period_s)
        controller = Controller(
            bus=bus, aggregator=aggregator, root=root, rate_hz=args.rate_hz,
            mode=args.tick_mode, camera_source=args.camera_source, trigger=args.trigger,
        )
        components += [aggregator, controller]
        if args.no_sim and isinstance(clock, SimClock):
            follow_sim_clock(bus, clock, clock_errors)
            print(f"  no simulator here: following the simulation time on {bus.keys.clock}",
                  file=out)
        elif isinstance(clock, SimClock):
            world = World(ball_in_view(seed=args.seed))
            simulator = SimulatorComponent(bus=bus, world=world, clock=clock, speed=args.speed)
            components += simulated_devices(
                bus=bus, world=world, devices=devices,
                camera_latency_s=args.camera_latency_s, seed=args.seed,
            )
            components.append(simulator)
            print(f"  simulated Mini-WHEGS at {args.speed:g}x real time, devices: "
                  f"{', '.join(devices) or 'none'}", file=out)
        else:
            print("  no simulator: waiting for devices to attach over zenoh", file=out)
        health.start()
        for component in components:
            await component.start()
        print(f"  controller: {args.tick_mode} at {args.rate_hz:g} Hz, tree:", file=out)
        for line in root.render_tree().splitlines():
            print(f"    {line}", file=out)
        out.flush()
        started = time.monotonic()
        interactive = out.isatty()
        last_print = 0.0
        while args.duration is None or time.monotonic() - started < args.duration:
            await asyncio.sleep(min(0.1, args.status_period_s))
            now = time.monotonic()
            if args.quiet or now - last_print < args.status_period_s:
                continue
            last_print = now
            line = format_status(options.robot, now - started, controller, aggregator, health)
            if simulator is not None and (rtf := simulator.real_time_factor()):
                line += f" | sim {clock.now_ns() / 1e9:.1f}s x{rtf:.2f}"
            if interactive:
                out.write("\r\x1b[2K" + line[:200])
            else:
                out.write(line + "\n")
            out.flush()
        return 0
    finally:
        if not args.quiet and out.isatty():
            out.write("\n")
        for component in reversed(components):
            await component.aclose()
        health.close()
        await bus.aclose()
        print("ubf_async: stopped", file=out)
        out.flush()


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=args.log_level, format="%(asctime)s %(levelname)s %(name)s: %(message)s"
    )
    if args.sim_time and not args.no_sim:
        build_parser().error("--sim-time only makes sense with --no-sim")
    if args.tick_mode == TickMode.EVENT and not args.trigger:
        build_parser().error("--tick event needs --trigger SOURCE")

    async def runner() -> int:
        task = asyncio.current_task()
        loop = asyncio.get_running_loop()
        assert task is not None
        with contextlib.suppress(NotImplementedError):  # no signal handlers on some platforms
            loop.add_signal_handler(signal.SIGTERM, task.cancel)
        try:
            return await run_robot(args)
        except asyncio.CancelledError:
            return 0
        except ConnectionError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2

    try:
        return asyncio.run(runner())
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
