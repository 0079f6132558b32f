"""One simulated world, many robots: the world process of a fleet.

``python -m ubf_async.fleet FLEET.yaml`` starts a router, this world, and one controller process
per robot (``launch ROBOT_FILE --no-sim --sim-time --robot NAME``). The world holds every robot
of the fleet in one pymunk space — they collide, and each sees the others in its camera and IR
(:meth:`~components.sim.world.physics.World.snapshot_for`: the other robots are dark boxes) —
with the scenario's arena, ball and scripts; the robots' start poses come from the fleet file. Each
robot's simulated devices run here, each on its robot's own bus (``ubf/<robot>/…``), all on one
simulated clock, which the simulator publishes on every robot's ``ubf/<robot>/clock``: the
controllers, in their own processes, follow it.
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from typing import Any, TextIO

from components.sim.runner.run import DEFAULT_SCENARIO, lateness_summary, rounded
from components.sim.runner.stepper import SimulatorComponent
from components.sim.scenarios.scenario import check_placement, load_scenario
from components.sim.world.config import WorldConfig, WorldPose
from components.sim.world.physics import World
from components.sim.world.snapshot import WorldSnapshot
from ubf_async.assembly.context import DeviceContext
from ubf_async.assembly.simulation import (
    CONTROLLER_SUMMARY_FIELDS,
    FleetMember,
    SimulationOptions,
    describe_speed,
)
from ubf_async.cli import ending
from ubf_async.clocks.clock import SimClock
from ubf_async.errors import ConfigurationError, ScenarioError
from ubf_async.runtime.bus import Bus
from ubf_async.runtime.component import Component
from ubf_async.runtime.gcfreeze import freeze_startup_objects
from ubf_async.wire.protocol import Message
from ubf_async.wire.topics import CONTROLLER_STATUS, PlainData

__all__ = ["FOUND_BEARING_DEG", "FOUND_DISTANCE_M", "MIN_SEPARATION_M", "PATH_SAMPLE_S",
           "WORLD_CLOSE_BOUND_S", "fleet_world_config", "found", "host_fleet"]

FOUND_DISTANCE_M = 1.0
FOUND_BEARING_DEG = 30.0
"""A robot has found the ball once it is within ``FOUND_DISTANCE_M`` of it, facing it within
``FOUND_BEARING_DEG`` (judged on the simulator's truth every 0.1 simulated s)."""
log = logging.getLogger(__name__)

WORLD_CLOSE_BOUND_S = 1.0
"""Wall time the world's end gives each of its components to close (the fleet launcher kills
a world still running 4 s after its SIGTERM, and its summary comes after them)."""

MIN_SEPARATION_M = 0.13
"""Closest two robots' centres may start (a Mini-WHEGS is 10 × 7 cm: its diagonal, rounded
up)."""


def fleet_world_config(base: WorldConfig, members: Sequence[FleetMember], *,
                       seed: int | None) -> WorldConfig:
    """``base`` (a scenario's world) with the members' start poses; refuses
    (:class:`ScenarioError`) a robot outside the arena, on an object, or on another robot."""
    if not members:
        raise ConfigurationError("a fleet needs at least one robot")
    poses = [WorldPose(x_m=m.x_m, y_m=m.y_m, heading_rad=math.radians(m.heading_deg))
             for m in members]
    for member, pose in zip(members, poses, strict=True):
        check_placement(replace(base, robot_start=pose), where=f"robot {member.name}")
    for i, a in enumerate(members):
        for b in members[i + 1:]:
            gap = math.hypot(a.x_m - b.x_m, a.y_m - b.y_m)
            if gap < MIN_SEPARATION_M:
                raise ScenarioError(f"robots {a.name} and {b.name} start {gap:.3f} m apart: "
                                    f"they would overlap (keep ≥ {MIN_SEPARATION_M} m)")
    config = replace(base, robot_start=poses[0], more_robots=tuple(poses[1:]))
    return config if seed is None else replace(config, seed=seed)


def found(snapshot: WorldSnapshot) -> bool:
    """Whether the robot of ``snapshot`` has found its ball (near it and facing it)."""
    robot, ball = snapshot.robot, snapshot.ball
    if ball is None:
        return False
    dx, dy = ball.x_m - robot.x_m, ball.y_m - robot.y_m
    bearing = math.degrees(math.atan2(dy, dx) - robot.heading_rad)
    bearing = (bearing + 180.0) % 360.0 - 180.0
    return math.hypot(dx, dy) <= FOUND_DISTANCE_M and abs(bearing) <= FOUND_BEARING_DEG


def _keep_status(statuses: list[dict[str, Any]], index: int
                 ) -> Callable[[str, Message[PlainData], int], None]:
    def on_status(key: str, message: Message[PlainData], received_ns: int) -> None:
        statuses[index] = dict(message.data)

    return on_status


async def host_fleet(*, buses: Sequence[Bus], clock: SimClock, members: Sequence[FleetMember],
                     options: SimulationOptions, out: TextIO) -> dict[str, Any]:
    """The world of ``members`` (see the module docstring) until ``options.duration_s``
    simulated seconds have passed, or until cancelled; returns the world's summary."""
    if len(buses) != len(members):
        raise ValueError(f"{len(members)} robots but {len(buses)} buses")
    if not options.speed > 0:
        raise ConfigurationError(f"--speed must be > 0, got {options.speed:g}")
    scenario = load_scenario(options.scenario or DEFAULT_SCENARIO)
    config = fleet_world_config(scenario.world, members, seed=options.seed)
    world = World(config)
    scenario.install(world)
    simulator = SimulatorComponent(bus=buses[0], world=world, clock=clock, speed=options.speed,
                                   more_robots=buses[1:],
                                   lockstep_participants=options.lockstep_participants)
    components = [*_fleet_devices(world, buses, clock, members, seed=config.seed),
                  simulator]  # the simulator last: time starts once the devices hold it
    # Each controller's newest status, heard in simulated time: in lockstep the status of
    # an instant arrives before the controller acknowledges it, so these are the same
    # however fast the machine.
    statuses: list[dict[str, Any]] = [{} for _ in members]
    malformed: dict[str, int] = {}
    subscriptions = [bus.subscribe_topic(CONTROLLER_STATUS.key(bus.keys, "controller"),
                                         CONTROLLER_STATUS, _keep_status(statuses, index),
                                         malformed)
                     for index, bus in enumerate(buses)]
    paths = _Paths(world)
    print(f"world: {scenario.name!r} with {len(members)} robots "
          f"({', '.join(m.name for m in members)}), {describe_speed(options.speed)}, "
          f"seed {config.seed}", file=out, flush=True)
    try:
        for component in components:
            await component.start()
        freeze_startup_objects()  # the world's start-up objects: out of the collector's way
        start_s = world.time_s
        end_ns = None if options.duration_s is None else round(
            (start_s + options.duration_s) * 1e9)
        if end_ns is not None:
            # Simulated time stops exactly at the end, however late this task notices it.
            clock.hold(end_ns)
        try:
            while end_ns is None or clock.now_ns() < end_ns:
                await clock.sleep(PATH_SAMPLE_S)
                paths.sample(world, since_s=start_s)
        except asyncio.CancelledError:
            # Stopped (SIGTERM, Ctrl-C): the run so far is still summarised and saved.
            print(f"world: stopped at {world.time_s:.1f} simulated s", file=out, flush=True)
        # What the controllers had said by the end's instant (statuses of the end itself
        # would come after it, while closing: not waited for).
        statuses = [dict(status) for status in statuses]
    finally:
        end = ending.Ending(log)
        for component in reversed(components):
            await end.step(f"closing {component.name}", component.aclose,
                           bound_s=WORLD_CLOSE_BOUND_S)
        for subscription in subscriptions:
            subscription.close()
    rtf = simulator.real_time_factor()
    summary = _fleet_summary(scenario.name, world, members, paths, statuses, rtf=rtf,
                             lateness=simulator.step_lateness_s)
    print(f"world: {world.time_s:.1f} simulated s at {rtf or 0:.2f}x real time", file=out,
          flush=True)
    return summary


PATH_SAMPLE_S = 0.1
"""How often (simulated s) the robots' paths are sampled: distance travelled, ball found."""


def _fleet_devices(world: World, buses: Sequence[Bus], clock: SimClock,
                   members: Sequence[FleetMember], *, seed: int) -> list[Component]:
    """Each robot's simulated devices, on its own bus, with its odometry in the world's frame
    (its encoders start from its start pose)."""
    components: list[Component] = []
    for index, (member, bus) in enumerate(zip(members, buses, strict=True)):
        origin = {"origin_x_m": member.x_m, "origin_y_m": member.y_m,
                  "origin_heading_deg": member.heading_deg}
        context = DeviceContext(bus=bus, clock=clock, seed=seed,
                                simulation=world.robot(index), extras=origin)
        components += [device.build(context=context) for device in member.devices]
    return components


class _Paths:
    """Each robot's path, sampled: its start, distance travelled, when it first found the
    ball (simulated s since the start)."""

    def __init__(self, world: World) -> None:
        self.starts = [world.snapshot_for(i).robot for i in range(world.robot_count)]
        self.travelled = [0.0] * world.robot_count
        self.found_s: list[float | None] = [None] * world.robot_count
        self._last = [(p.x_m, p.y_m) for p in self.starts]

    def sample(self, world: World, *, since_s: float) -> None:
        for i in range(world.robot_count):
            snapshot = world.snapshot_for(i)
            now = snapshot.robot
            last = self._last[i]
            self.travelled[i] += math.hypot(now.x_m - last[0], now.y_m - last[1])
            self._last[i] = (now.x_m, now.y_m)
            if self.found_s[i] is None and snapshot.ball is not None and found(snapshot):
                self.found_s[i] = world.time_s - since_s


def _fleet_summary(scenario: str, world: World, members: Sequence[FleetMember], paths: _Paths,
                   statuses: Sequence[Mapping[str, Any]], *, rtf: float | None,
                   lateness: Sequence[float]) -> dict[str, Any]:
    """The world's summary: the run, and per robot its start and end, distance, when it found
    the ball, and what its controller last said."""
    ends = [world.snapshot_for(i).robot for i in range(world.robot_count)]
    found_s = paths.found_s
    summary = {
        "scenario": scenario,
        "sim_time_s": world.time_s,
        "real_time_factor": rtf,
        "step_lateness": lateness_summary(lateness),
        "first_found_s": min((f for f in found_s if f is not None), default=None),
        "all_found_s": None if None in found_s else max(f for f in found_s if f is not None),
        "robots": {
            member.name: {
                "start": {"x_m": s.x_m, "y_m": s.y_m,
                          "heading_deg": math.degrees(s.heading_rad)},
                "end": {"x_m": e.x_m, "y_m": e.y_m, "heading_deg": math.degrees(e.heading_rad)},
                "travelled_m": paths.travelled[i],
                "found_s": found_s[i],
                "controller": {field: statuses[i].get(field)
                               for field in CONTROLLER_SUMMARY_FIELDS},
            }
            for i, (member, s, e) in enumerate(zip(members, paths.starts, ends, strict=True))
        },
    }
    return rounded(summary)
