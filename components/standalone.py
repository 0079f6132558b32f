"""Running one device component as its own process: ``python -m components.<device>``.

Every device entry point shares the connection flags of all ubf_async entry points
(``--connect/-e --listen/-l --mode/-m --config --robot``) plus ``--duration`` and
``--log-level``, and adds its own options. With a simulator backend (the default) the process
follows the simulation time published on ``ubf/<robot>/clock`` and reads the world from the
running simulator over the bus (:class:`~components.sim.remote.RemoteWorld`), so a device can
be added to, or removed from, a running simulated robot at any time.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
from collections.abc import Callable, Sequence

from components.sim.remote import RemoteWorld
from ubf_async.bus import (
    Bus,
    HelpFormatter,
    add_connection_arguments,
    connection_options,
    follow_sim_clock,
)
from ubf_async.cli import run_main
from ubf_async.clock import Clock, SimClock, WallClock
from ubf_async.component import Component

Build = Callable[[Bus, RemoteWorld | None, argparse.Namespace], Component]


def run_device(
    *,
    prog: str,
    description: str,
    add_arguments: Callable[[argparse.ArgumentParser], None],
    build: Build,
    uses_simulator: Callable[[argparse.Namespace], bool] = lambda args: True,
    argv: Sequence[str] | None = None,
) -> int:
    parser = argparse.ArgumentParser(prog=prog, description=description,
                                     formatter_class=HelpFormatter)
    add_connection_arguments(parser)
    add_arguments(parser)
    run = parser.add_argument_group("run")
    run.add_argument("--duration", type=float, default=None, metavar="S",
                     help="stop after S wall-clock seconds (default: until Ctrl-C or SIGTERM)")
    run.add_argument("--wait-for-sim-s", type=float, default=10.0, metavar="S",
                     help="how long to wait for the simulator's world before giving up")
    run.add_argument("--log-level", default="WARNING",
                     choices=["DEBUG", "INFO", "WARNING", "ERROR"])
    args = parser.parse_args(argv)
    logging.basicConfig(level=args.log_level,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")

    return run_main(lambda: _serve(args, build, uses_simulator(args)), prog=prog)


async def _serve(args: argparse.Namespace, build: Build, simulated: bool) -> int:
    options = connection_options(args)
    clock: Clock = SimClock() if simulated else WallClock()
    bus = await Bus.open(options, clock=clock)
    world: RemoteWorld | None = None
    component: Component | None = None
    try:
        if simulated:
            assert isinstance(clock, SimClock)
            follow_sim_clock(bus, clock, {})
            world = RemoteWorld(bus, seed=getattr(args, "seed", 0) or 0)
            world.start()
            await world.wait_ready(args.wait_for_sim_s)
        component = build(bus, world, args)
        await component.start()
        print(f"{component.name}: attached to robot {options.robot!r}"
              + (" (simulated)" if simulated else ""), flush=True)
        forever = asyncio.Event()  # never set: we run until cancelled (SIGTERM/Ctrl-C)
        if args.duration is None:
            await forever.wait()
        else:
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(forever.wait(), args.duration)
        return 0
    finally:
        if component is not None:
            await component.aclose()
        if world is not None:
            world.close()
        await bus.aclose()
