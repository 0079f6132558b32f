"""Running one device component as its own process: ``python -m components.<device>``.

Every device entry point shares the connection flags of all ubf_async entry points
(``--connect/-e --listen/-l --mode/-m --config --robot``) plus ``--backend``, ``--duration``,
``--wait-for-sim-s`` and ``--log-level``, and adds its own options, which it maps to the
parameters of its device kind's ``build_device``.

The device and its backend are looked up in the registry (:mod:`ubf_async.assembly.registry`)
exactly as launch looks them up for a robot file: ``--backend`` lists the backends registered for
the kind. When the backend needs a simulator (its ``requires_simulator``), the process follows the
simulation time published on ``ubf/<robot>/clock`` and gets the running simulator's world from that
simulator plug-in's ``attach()``, so a device can be added to, or removed from, a running simulated
robot at any time. Nothing that stamps is built before that time has been heard (waiting at most
``--wait-for-sim-s``, and saying so after a second): the device's first sample is on the robot's
clock. This module knows no simulator by name.

Any other backend (real hardware, the radio on a terminal) stamps on the robot's clock too:
with ``--clock auto`` (the default) it waits until the robot says which clock it runs on,
however long the robot takes to start — simulated time (``ubf/<robot>/clock``: followed), or
its host's ``CLOCK_MONOTONIC`` (followed through ``ubf/<robot>/time`` from another host) —
and takes this host's clock only when the robot says nothing of it within ``--clock-wait-s``;
its start-up line says which (:func:`ubf_async.clocks.follow.follow_robot_clock`).

Whatever the backend, the process says on its stderr, at once, when the robot refuses its
samples, and why (:class:`ubf_async.runtime.refusals.RefusalWatch`).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import yaml

from components.devices import make_backend, make_device
from ubf_async.assembly import registry
from ubf_async.assembly.backend import Backend
from ubf_async.assembly.context import DeviceContext
from ubf_async.assembly.devices import requires_simulator
from ubf_async.cli.args import HelpFormatter, add_connection_arguments, connection_options
from ubf_async.cli.attach import DEFAULT_ATTACH_TIMEOUT_S, wait_for_robot
from ubf_async.cli.run import run_main
from ubf_async.clocks import follow
from ubf_async.clocks.clock import Clock
from ubf_async.net.options import DEFAULT_LISTEN
from ubf_async.runtime import refusals, timekeepers
from ubf_async.runtime.bus import Bus
from ubf_async.runtime.component import Component, ensure_name_free

__all__ = ["Device", "Params", "add_backend_argument", "run_device"]

Params = Callable[[argparse.Namespace], dict[str, Any]]
"""Maps the parsed command line to keyword parameters (of the device or of its backend)."""


def _say(line: str) -> None:
    # stderr: a device's stdout may carry its data (the radio's received messages).
    print(line, file=sys.stderr, flush=True)


def _no_params(args: argparse.Namespace) -> dict[str, Any]:
    return {}


def add_backend_argument(group: argparse._ArgumentGroup, kind: str, *, default: str,
                         help: str) -> None:
    """``--backend``: the backends registered for ``kind`` (entry points ``<kind>.<name>``),
    and ``--backend-params``: their parameters, as a robot file gives them."""
    group.add_argument("--backend", choices=registry.backends_for(kind), default=default,
                       help=help)
    group.add_argument("--backend-params", type=_yaml_mapping, default={}, metavar="YAML",
                       help="the backend's parameters as in a robot file's backend_params, "
                            "e.g. '{left_pin: GPIO12, right_pin: GPIO13}' (docs/hardware.md)")


def _yaml_mapping(text: str) -> dict[str, Any]:
    try:
        value = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise argparse.ArgumentTypeError(f"not YAML: {exc}") from None
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise argparse.ArgumentTypeError(f"expected a mapping like '{{key: value}}', got "
                                         f"{text!r}")
    return value


def run_device(
    *,
    kind: str,
    prog: str,
    description: str,
    add_arguments: Callable[[argparse.ArgumentParser], None],
    device_params: Params = _no_params,
    backend_params: Params = _no_params,
    seed: Callable[[argparse.Namespace], int] = lambda args: 0,
    argv: Sequence[str] | None = None,
) -> int:
    """Parse the command line and run one ``kind`` device until stopped.

    ``add_arguments`` adds the device's own options, ``--name`` and ``--backend`` (see
    :func:`add_backend_argument`) among them; ``device_params`` / ``backend_params`` map them
    to the keyword parameters of the device kind's factory / of the backend's; ``seed`` gives
    the run's seed (sensor noise).
    """
    parser = argparse.ArgumentParser(prog=prog, description=description,
                                     formatter_class=HelpFormatter)
    # Like every tool that attaches: to the robot where launch listens, unless told otherwise.
    add_connection_arguments(parser, default_connect=[DEFAULT_LISTEN])
    add_arguments(parser)
    run = parser.add_argument_group("run")
    run.add_argument("--duration", type=float, default=None, metavar="S",
                     help="stop after S wall-clock seconds (default: until Ctrl-C or SIGTERM)")
    run.add_argument("--wait-for-robot-s", type=float, default=DEFAULT_ATTACH_TIMEOUT_S,
                     metavar="S",
                     help="with --connect: how long to wait for the robot to answer before "
                          "giving up")
    run.add_argument("--wait-for-sim-s", type=float, default=10.0, metavar="S",
                     help="with a simulated backend: how long to wait for the simulator's "
                          "time, then for its world, before giving up")
    run.add_argument("--clock", choices=("auto", "wall", "sim", "robot"), default="auto",
                     help="with a backend that needs no simulator: the robot clock to stamp "
                          "with: wall (this host's CLOCK_MONOTONIC), sim (follow "
                          "ubf/<robot>/clock), robot (the robot host's clock through "
                          "ubf/<robot>/time: on another host), auto (the one the robot "
                          "says it runs on)")
    run.add_argument("--clock-wait-s", type=float, default=follow.DEFAULT_CLOCK_WAIT_S,
                     metavar="S", help="with --clock auto: how long to wait for the robot to "
                                       "say which clock it runs on (a running robot does "
                                       "within a second) before stamping with this host's")
    run.add_argument("--lockstep", action="store_true",
                     help="on a simulated robot: take part in the simulator's lockstep, so "
                          "every sample counts at the simulated instant it was taken and a "
                          "run is repeatable (docs/protocol.md, Lockstep)")
    run.add_argument("--log-level", default="WARNING",
                     choices=["DEBUG", "INFO", "WARNING", "ERROR"])
    args = parser.parse_args(argv)
    logging.basicConfig(level=args.log_level,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    device = Device(kind=kind, name=args.name, backend=args.backend,
                    params=device_params(args),
                    backend_params={**backend_params(args),
                                    **getattr(args, "backend_params", {})},
                    seed=seed(args), wait_for_sim_s=args.wait_for_sim_s,
                    wait_for_robot_s=args.wait_for_robot_s, clock=args.clock,
                    clock_wait_s=args.clock_wait_s, lockstep=args.lockstep)
    return run_main(lambda: device.serve(args, duration_s=args.duration), prog=prog)


@dataclass(frozen=True, kw_only=True)
class Device:
    """One device to run in this process: its kind, name, backend and their parameters."""

    kind: str
    name: str
    backend: str
    params: dict[str, Any] = field(default_factory=dict)
    backend_params: dict[str, Any] = field(default_factory=dict)
    seed: int = 0
    wait_for_sim_s: float = 10.0
    wait_for_robot_s: float = DEFAULT_ATTACH_TIMEOUT_S
    clock: follow.ClockMode = "auto"
    """The robot clock for a backend that needs no simulator (``--clock``)."""
    clock_wait_s: float = follow.DEFAULT_CLOCK_WAIT_S
    lockstep: bool = False
    """Take part in the simulator's lockstep (``--lockstep``)."""

    async def serve(self, args: argparse.Namespace, *, duration_s: float | None) -> int:
        """Attach to the robot on the bus ``args`` names; run for ``duration_s`` wall
        seconds, or until cancelled (SIGTERM, Ctrl-C).

        Before anything starts it checks that the robot answers at ``--connect`` (within
        ``wait_for_robot_s``) and that no component of the robot already has this device's
        name; either is a :class:`~ubf_async.errors.UbfError` with a one-line message."""
        factory = registry.get_backend(self.kind, self.backend)
        simulator_name = requires_simulator(factory)
        simulator = registry.SIMULATORS.get(simulator_name)() if simulator_name else None
        options = connection_options(args)
        bus = await Bus.open(options, ordered=self.lockstep)
        world: Any = None
        backend: Backend | None = None
        component: Component | None = None
        participant: Component | None = None
        watch: refusals.RefusalWatch | None = None
        try:
            await wait_for_robot(bus, timeout_s=self.wait_for_robot_s)
            clock = await self._robot_clock(bus, simulated=simulator is not None)
            if simulator is not None:
                world = await simulator.attach(bus=bus, seed=self.seed,
                                               wait_s=self.wait_for_sim_s)
            context = DeviceContext(bus=bus, clock=clock, seed=self.seed, simulation=world)
            backend = make_backend(self.kind, self.backend, context=context,
                                   params=self.backend_params)
            component = make_device(self.kind, context=context, backend=backend,
                                    name=self.name, params=self.params)
            await ensure_name_free(bus, component.name,
                                   hint=f"start it with another --name than {self.name!r}")
            # Before the first sample, so that the robot's first refusal is heard (on stderr).
            watch = refusals.RefusalWatch(bus, mine=component.publishes, who=component.name)
            watch.start()
            await component.start()
            if self.lockstep:
                participant = timekeepers.LockstepParticipant(bus=bus, participant=component.name)
                await participant.start()
            print(f"{component.name}: attached to robot {options.robot!r}"
                  + (" (simulated)" if simulator is not None else "")
                  + f", stamping with {follow.describe(clock, robot=options.robot)}",
                  flush=True)
            forever = asyncio.Event()  # never set: we run until cancelled (SIGTERM/Ctrl-C)
            if duration_s is None:
                await forever.wait()
            else:
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(forever.wait(), duration_s)
            return 0
        finally:
            if participant is not None:
                await participant.aclose()
            if component is not None:
                await component.aclose()  # closes its backend too
            elif backend is not None:
                await backend.aclose()  # built, but its device was not
            if world is not None:
                world.close()
            if watch is not None:
                watch.close()
            await bus.aclose()

    async def _robot_clock(self, bus: Bus, *, simulated: bool) -> Clock:
        """The robot's clock, once this process has heard it — before anything is built
        that stamps: a simulated clock that has heard no time yet stands at 0, and a first
        sample stamped with it was taken by the robot for another clock (issue 35). A
        backend on the simulator follows its time (waiting at most ``wait_for_sim_s``), any
        other the clock ``--clock`` says."""
        if not simulated:
            return await follow.follow_robot_clock(bus, mode=self.clock,
                                                        wait_s=self.clock_wait_s, say=_say)
        try:
            return await asyncio.wait_for(
                follow.follow_robot_clock(bus, mode="sim", say=_say), self.wait_for_sim_s)
        except TimeoutError:
            raise ConnectionError(
                f"no simulator is publishing {bus.keys.clock} (waited "
                f"{self.wait_for_sim_s:g} s): start one with python -m ubf_async.launch and "
                f"pass its endpoint with --connect") from None
