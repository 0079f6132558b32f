"""The simulated arena in a live view (:mod:`ubf_async.services.liveview`): ``sim/world`` →
``/arena`` (``foxglove.SceneUpdate`` in frame ``world``).

Walls, box obstacles, distractors, the ball and the robot's body as 3-D primitives. The
simulator publishes its world at 50 Hz of simulated time; the scene is sent at most every
:data:`SCENE_PERIOD_S` of it (a viewer needs no more, and each update is a few hundred bytes per
object). Registered as the ``sim.world`` entry point of ``ubf_async.live_views``.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from typing import Any

from components.miniwhegs import MINI_WHEGS
from components.sim.world.snapshot import WorldSnapshot
from components.sim.world.snapshot_data import snapshot_from_data
from ubf_async.services.liveview import LiveMessage, foxglove_message, pose, rgba, timestamp
from ubf_async.wire.protocol import Message

__all__ = ["BODY_HEIGHT_M", "ROBOT_RGB", "SCENE_PERIOD_S", "WALL_THICKNESS_M", "ArenaConverter",
           "arena_converter", "scene"]

SCENE_PERIOD_S = 0.1
WALL_THICKNESS_M = 0.01
BODY_HEIGHT_M = 0.04
ROBOT_RGB = (90, 90, 100)


class ArenaConverter:
    schemas = frozenset({"sim.world"})

    def __init__(self) -> None:
        self._next_s = -math.inf

    def convert(self, source: str, message: Message[Any],
                log_time_ns: int) -> Iterator[LiveMessage]:
        world = snapshot_from_data(message.data)
        if world.time_s < self._next_s:
            return
        self._next_s = world.time_s + SCENE_PERIOD_S
        yield foxglove_message("/arena", scene(world, message.stamp_ns), log_time_ns)


def scene(world: WorldSnapshot, stamp_ns: int) -> Any:
    """The world as a ``foxglove.SceneUpdate``: one entity per object, in frame ``world``."""
    from foxglove.messages import (
        CubePrimitive,
        CylinderPrimitive,
        SceneEntity,
        SceneUpdate,
        SpherePrimitive,
        Vector3,
    )

    stamp = timestamp(stamp_ns)
    entities = []
    walls = [CubePrimitive(
        pose=pose((w.x1_m + w.x2_m) / 2, (w.y1_m + w.y2_m) / 2, w.height_m / 2,
                  math.atan2(w.y2_m - w.y1_m, w.x2_m - w.x1_m)),
        size=Vector3(x=math.hypot(w.x2_m - w.x1_m, w.y2_m - w.y1_m), y=WALL_THICKNESS_M,
                     z=w.height_m),
        color=rgba(w.color, 0.6)) for w in world.walls]
    boxes = [CubePrimitive(pose=pose(b.x_m, b.y_m, b.height_m / 2, b.yaw_rad),
                           size=Vector3(x=b.length_m, y=b.width_m, z=b.height_m),
                           color=rgba(b.color)) for b in world.boxes]
    entities.append(SceneEntity(timestamp=stamp, frame_id="world", id="arena",
                                cubes=walls + boxes))
    spheres, cylinders, cubes = [], [], []
    for d in world.distractors:
        if d.kind == "sphere":
            spheres.append(SpherePrimitive(pose=pose(d.x_m, d.y_m, d.radius_m),
                                           size=Vector3(x=2 * d.radius_m, y=2 * d.radius_m,
                                                        z=2 * d.radius_m),
                                           color=rgba(d.color)))
        elif d.kind == "cylinder":
            cylinders.append(CylinderPrimitive(
                pose=pose(d.x_m, d.y_m, d.height_m / 2),
                size=Vector3(x=2 * d.radius_m, y=2 * d.radius_m, z=d.height_m),
                bottom_scale=1.0, top_scale=1.0, color=rgba(d.color)))
        else:
            cubes.append(CubePrimitive(pose=pose(d.x_m, d.y_m, d.height_m / 2, d.yaw_rad),
                                       size=Vector3(x=d.length_m, y=d.width_m, z=d.height_m),
                                       color=rgba(d.color)))
    if world.ball is not None:
        r = world.ball.radius_m
        spheres.append(SpherePrimitive(pose=pose(world.ball.x_m, world.ball.y_m, r),
                                       size=Vector3(x=2 * r, y=2 * r, z=2 * r),
                                       color=rgba(world.ball.color)))
    entities.append(SceneEntity(timestamp=stamp, frame_id="world", id="objects",
                                spheres=spheres, cylinders=cylinders, cubes=cubes))
    robot = world.robot
    entities.append(SceneEntity(timestamp=stamp, frame_id="world", id="robot", cubes=[
        CubePrimitive(pose=pose(robot.x_m, robot.y_m, BODY_HEIGHT_M / 2, robot.heading_rad),
                      size=Vector3(x=MINI_WHEGS.length_m, y=MINI_WHEGS.width_m,
                                   z=BODY_HEIGHT_M),
                      color=rgba(ROBOT_RGB))]))
    return SceneUpdate(entities=entities)


def arena_converter() -> ArenaConverter:
    """The ``ubf_async.live_views`` entry point."""
    return ArenaConverter()
