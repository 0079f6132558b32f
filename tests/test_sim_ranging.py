"""Ray casting for the IR range finders: distances are measured from the sensor's mount point."""

from __future__ import annotations

import math

import pytest

from components.range.backend import MountPose
from components.sim.backends.devices import SimRangeBackend
from components.sim.world.config import (
    BallConfig,
    BoxObstacle,
    Distractor,
    Wall,
    WorldConfig,
    WorldPose,
)
from components.sim.world.physics import World
from components.sim.world.ranging import beam_distance_m, ray_box, ray_circle, ray_segment

FRONT = MountPose(x_m=0.05, y_m=0.0, yaw_rad=0.0)
LEFT_SIDE = MountPose(x_m=0.0, y_m=0.035, yaw_rad=math.pi / 2)


def wall_across_x(x: float) -> Wall:
    return Wall(x1_m=x, y1_m=-1.0, x2_m=x, y2_m=1.0)


def test_front_sensor_reads_wall_distance_minus_mount_offset() -> None:
    # The wall is 0.5 m ahead of the robot's centre; the sensor sits 5 cm ahead of the centre.
    snap = World(WorldConfig(walls=(wall_across_x(0.5),))).snapshot()
    assert beam_distance_m(snap, FRONT, 1.5) == pytest.approx(0.45)
    # 0.5 m ahead of the sensor itself reads 0.5 m.
    snap = World(WorldConfig(walls=(wall_across_x(0.55),))).snapshot()
    assert beam_distance_m(snap, FRONT, 1.5) == pytest.approx(0.5)


def test_robot_pose_is_applied() -> None:
    start = WorldPose(x_m=1.0, y_m=1.0, heading_rad=math.pi / 2)
    wall = Wall(x1_m=0.0, y1_m=1.55, x2_m=2.0, y2_m=1.55)
    snap = World(WorldConfig(robot_start=start, walls=(wall,))).snapshot()
    assert beam_distance_m(snap, FRONT, 1.5) == pytest.approx(0.5)


def test_side_sensor_reads_side_wall() -> None:
    side_wall = Wall(x1_m=-1.0, y1_m=0.4, x2_m=1.0, y2_m=0.4)
    snap = World(WorldConfig(walls=(side_wall, wall_across_x(0.3)))).snapshot()
    assert beam_distance_m(snap, LEFT_SIDE, 0.8) == pytest.approx(0.4 - 0.035)
    assert beam_distance_m(snap, FRONT, 0.8) == pytest.approx(0.25)


def test_nothing_in_range_is_none() -> None:
    snap = World(WorldConfig(walls=(wall_across_x(1.0),))).snapshot()
    assert beam_distance_m(snap, FRONT, 0.8) is None
    assert beam_distance_m(snap, LEFT_SIDE, 1.5) is None
    assert beam_distance_m(World().snapshot(), FRONT, 10.0) is None
    with pytest.raises(ValueError):
        beam_distance_m(snap, FRONT, 0.0)


def test_ball_boxes_and_distractors_are_hit() -> None:
    snap = World(
        WorldConfig(
            ball=BallConfig(x_m=0.5, y_m=0.0),
            boxes=(BoxObstacle(x_m=0.0, y_m=0.5, length_m=0.2, width_m=0.2),),
            distractors=(Distractor(kind="cylinder", x_m=0.0, y_m=-0.6, radius_m=0.05),),
        )
    ).snapshot()
    assert beam_distance_m(snap, FRONT, 1.0) == pytest.approx(0.5 - 0.0325 - 0.05)
    assert beam_distance_m(snap, MountPose(x_m=0.0, y_m=0.0, yaw_rad=math.pi / 2), 1.0) == (
        pytest.approx(0.4)
    )
    assert beam_distance_m(snap, MountPose(x_m=0.0, y_m=0.0, yaw_rad=-math.pi / 2), 1.0) == (
        pytest.approx(0.55)
    )


def test_ray_primitives() -> None:
    assert ray_segment((0, 0), (1, 0), (2, -1), (2, 1)) == pytest.approx(2.0)
    assert ray_segment((0, 0), (-1, 0), (2, -1), (2, 1)) is None
    assert ray_segment((0, 0), (1, 0), (2, 0.5), (2, 1)) is None
    assert ray_circle((0, 0), (1, 0), (1, 0), 0.25) == pytest.approx(0.75)
    assert ray_circle((0, 0), (1, 0), (0.1, 0), 0.25) == 0.0  # inside
    assert ray_circle((0, 0), (1, 0), (1, 1), 0.25) is None
    assert ray_box((0, 0), (1, 0), (1, 0), math.pi / 4, 0.2, 0.2) == pytest.approx(
        1 - 0.1 * math.sqrt(2)
    )
    assert ray_box((0, 0), (0, 1), (1, 0), 0.0, 0.2, 0.2) is None


def test_range_backend_reads_the_latest_snapshot() -> None:
    world = World(WorldConfig(ball=BallConfig(x_m=0.4, y_m=0.0)))
    backend = SimRangeBackend(world)
    assert backend.distance_m(FRONT, max_range_m=0.8) == pytest.approx(0.4 - 0.05 - 0.0325)
    world.place_ball(0.7, 0.0)
    assert backend.distance_m(FRONT, max_range_m=0.8) == pytest.approx(0.7 - 0.05 - 0.0325)
    assert backend.distance_m(FRONT, max_range_m=0.3) is None
