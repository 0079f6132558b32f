"""A fleet file, and a fleet's run in this process.

A fleet file (YAML, ``docs/fleet.md``) lists the robots — a name, a robot file and a start pose
each — and the world they share (a scenario's arena, ball and scripts, the speed, the seed).
:func:`load_fleet` reads and checks it; ``python -m ubf_async.fleet`` (:mod:`ubf_async.tools.fleet`)
runs it as processes around a router, and :func:`run_fleet` runs it in the calling process:
one simulated world holding every robot and its simulated devices, and every robot's
controller wired as launch wires it (:mod:`ubf_async.runs.wiring`), each on its robot's own
bus of one in-process network, all on one simulated clock advancing in lockstep, flat out.
Like :func:`ubf_async.runs.inprocess.run`, it is the same run whatever the machine and its
load, and leaves no thread or process behind.
"""

from __future__ import annotations

import dataclasses
import io
import math
from pathlib import Path
from typing import Annotated, Any, Literal

import msgspec
from msgspec import Meta

from ubf_async.assembly.registry import SIMULATORS
from ubf_async.assembly.robotfile import Robot, load_robot
from ubf_async.assembly.simulation import FLAT_OUT, FleetMember, SimulationOptions
from ubf_async.clocks.clock import SimClock
from ubf_async.errors import ConfigurationError, ProtocolError
from ubf_async.net.inprocess import InProcessTransport
from ubf_async.net.options import ConnectionOptions
from ubf_async.runs import inprocess, wiring
from ubf_async.runtime.bus import Bus
from ubf_async.wire.keys import Keys

__all__ = ["DEFAULT_ROUTER", "MAX_ROBOTS", "Finite", "Fleet", "FleetFile", "FleetRobot",
           "FleetWorld", "StartPose", "load_fleet", "members_of", "run_fleet", "world_options"]

MAX_ROBOTS = 32
DEFAULT_ROUTER = "tcp/127.0.0.1:7447"

Finite = Annotated[float, Meta(ge=-1e6, le=1e6)]


class StartPose(msgspec.Struct, forbid_unknown_fields=True, frozen=True):
    x_m: Finite
    y_m: Finite
    heading_deg: Annotated[float, Meta(ge=-360.0, le=360.0)] = 0.0


class FleetRobot(msgspec.Struct, forbid_unknown_fields=True, frozen=True):
    name: Annotated[str, Meta(min_length=1, max_length=64)]
    start: StartPose
    robot_file: str = "mini-whegs"


class FleetWorld(msgspec.Struct, forbid_unknown_fields=True, frozen=True):
    scenario: str | None = None
    """A built-in scenario or a scenario file: the arena, ball and scripts (its robot start is
    replaced by the robots'); ``None``: the simulator's default."""
    speed: Annotated[float, Meta(gt=0.0, le=1000.0)] | Literal["max"] = 1.0
    """× real time, or ``max``: flat out."""
    seed: int | None = None
    duration_s: Annotated[float, Meta(gt=0.0, le=1e6)] | None = None


class FleetFile(msgspec.Struct, forbid_unknown_fields=True, frozen=True):
    robots: Annotated[list[FleetRobot], Meta(min_length=1, max_length=MAX_ROBOTS)]
    world: FleetWorld = FleetWorld()
    router: str = DEFAULT_ROUTER
    """The router's endpoint: where the launcher starts one, and where everyone connects."""


@dataclasses.dataclass(slots=True)
class Fleet:
    """A fleet file, checked: every robot file loaded, names unique, one simulator."""

    spec: FleetFile
    source: Path
    robots: dict[str, Robot]
    simulator: str


def load_fleet(path: Path) -> Fleet:
    """Read and check a fleet file; :class:`ConfigurationError` naming what is wrong."""
    if not path.is_file():
        raise ConfigurationError(f"no fleet file {path}")
    try:
        spec = msgspec.yaml.decode(path.read_bytes(), type=FleetFile)
    except (msgspec.ValidationError, msgspec.DecodeError) as exc:
        raise ConfigurationError(f"{path}: {exc}") from None
    names = [r.name for r in spec.robots]
    doubled = sorted({n for n in names if names.count(n) > 1})
    if doubled:
        raise ConfigurationError(f"{path}: robot names must be unique; twice: "
                                 f"{', '.join(doubled)}")
    robots: dict[str, Robot] = {}
    simulators: set[str] = set()
    for entry in spec.robots:
        try:
            Keys(entry.name)
        except ProtocolError as exc:
            raise ConfigurationError(f"{path}: robot {entry.name!r}: {exc}") from None
        robot_file = entry.robot_file
        if not Path(robot_file).is_absolute() and (path.parent / robot_file).is_file():
            robot_file = str(path.parent / robot_file)  # relative to the fleet file
        robot = load_robot(robot_file, seed=spec.world.seed)
        needs = {d.requires_simulator for d in robot.devices if d.requires_simulator}
        if not needs:
            raise ConfigurationError(f"{path}: robot {entry.name}'s file {robot.source} has no "
                                     f"simulated device: nothing for the world to host")
        simulators |= needs
        robots[entry.name] = dataclasses.replace(robot, source=robot_file)
    if len(simulators) != 1:
        raise ConfigurationError(f"{path}: the robots need several simulators "
                                 f"({', '.join(sorted(simulators))}); a fleet shares one world")
    return Fleet(spec=spec, source=path, robots=robots, simulator=simulators.pop())


def members_of(fleet: Fleet) -> list[FleetMember]:
    """The fleet's robots as the simulator hosts them: name, start pose and the devices whose
    backends need the simulator."""
    return [FleetMember(name=entry.name, x_m=entry.start.x_m, y_m=entry.start.y_m,
                        heading_deg=entry.start.heading_deg,
                        devices=tuple(d for d in fleet.robots[entry.name].devices
                                      if d.requires_simulator))
            for entry in fleet.spec.robots]


def world_options(fleet: Fleet, *, lockstep_participants: int = 0) -> SimulationOptions:
    """The fleet file's ``world:`` as the simulator's options."""
    world = fleet.spec.world
    return SimulationOptions(
        scenario=world.scenario,
        speed=math.inf if world.speed == FLAT_OUT else float(world.speed),
        seed=world.seed, duration_s=world.duration_s,
        lockstep_participants=lockstep_participants)


def run_fleet(fleet: str | Path | Fleet, *, seed: int | None = None,
              duration_s: float | None = None) -> dict[str, Any]:
    """Run ``fleet`` (a fleet file, or one loaded) in this process, flat out, and return the
    world's summary (what ``python -m ubf_async.fleet … --summary`` writes under ``world``):
    per robot its start and end, the distance it travelled, when it found the ball, and what
    its controller last said. ``seed`` and ``duration_s`` override the file's ``world:``;
    a fleet runs until its duration, so one is needed (here or in the file). Raises
    :class:`~ubf_async.errors.UbfError` before anything runs."""
    loaded = fleet if isinstance(fleet, Fleet) else load_fleet(Path(fleet))
    world = loaded.spec.world
    duration = duration_s if duration_s is not None else world.duration_s
    if duration is None or not (math.isfinite(duration) and duration > 0):
        raise ConfigurationError(f"{loaded.source}: a fleet run in this process needs a "
                                 f"duration > 0 (world.duration_s, or duration_s=)")
    options = dataclasses.replace(world_options(loaded), speed=math.inf, duration_s=duration,
                                  seed=world.seed if seed is None else seed)
    # Each run builds the robots' trees afresh (a loaded fleet may be run again), their
    # behaviours drawing from the run's seed.
    robots = {name: robot.reseeded(options.seed) for name, robot in loaded.robots.items()}
    with inprocess.own_loop("ubf_async.runs.fleet.run_fleet()",
                            instead="run it in a worker thread (asyncio.to_thread)") as runner:
        return runner.run(_run_fleet(loaded, robots, options))


async def _run_fleet(fleet: Fleet, robots: dict[str, Robot],
                     options: SimulationOptions) -> dict[str, Any]:
    clock = SimClock()
    network = InProcessTransport()
    quiet = io.StringIO()
    runs: list[wiring.RobotRun] = []
    try:
        for entry in fleet.spec.robots:
            robot = robots[entry.name]
            connection = ConnectionOptions(robot=entry.name)
            run = wiring.RobotRun.on(Bus(transport=network, options=connection, clock=clock))
            runs.append(run)
            # Its devices live in the world (built there, on this same bus); its clock is
            # the world's, driven in this process.
            plan = wiring.RunPlan(
                robot=robot, devices=[], elsewhere=[d for d in robot.devices
                                                    if d.requires_simulator],
                simulator=None, sim_options=None,
                controller=wiring.ControllerSettings.of(robot), connection=connection,
                # Without a seed its behaviours draw from the robot file's, else 0, as a
                # launched controller's do (never from an unseeded generator).
                seed_given=options.seed is not None, follow_clock=False,
                status_on_robot_clock=True)
            wiring.build_robot(plan, run, quiet)
            wiring.add_clock_components(plan, run)
            await wiring.start(run)
        simulator = SIMULATORS.get(fleet.simulator)()
        return await simulator.host_fleet(buses=[run.bus for run in runs], clock=clock,
                                          members=members_of(fleet), options=options,
                                          out=quiet)
    finally:
        for run in reversed(runs):
            await wiring.end(run, quiet)
