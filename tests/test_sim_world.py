"""The pymunk world: skid-steer drive, motor characteristics, ball, walls, snapshots."""

from __future__ import annotations

import dataclasses
import math

import pytest

from components.miniwhegs import MINI_WHEGS
from components.motors.pwm import (
    LEFT_MOTOR,
    RIGHT_MOTOR,
    pulse_for_wheel_speed_ms,
    wheel_speed_rad_s,
)
from components.sim.world import (
    Arena,
    BallConfig,
    Pose2D,
    World,
    WorldConfig,
    wrap_angle,
)

RADIUS = MINI_WHEGS.wheel_radius_m


def run(world: World, seconds: float, dt: float = 0.01) -> None:
    for _ in range(round(seconds / dt)):
        world.step(dt)


def matched_pulses(left_ms: float) -> tuple[float, float]:
    """Left pulse and the right pulse that gives the same wheel speed."""
    omega = wheel_speed_rad_s(LEFT_MOTOR, left_ms)
    return left_ms, pulse_for_wheel_speed_ms(RIGHT_MOTOR, omega)


def test_straight_drive_moves_as_far_as_the_wheels_turned() -> None:
    world = World()
    world.set_motor_pulses(*matched_pulses(1.9))
    run(world, 2.0)
    r = world.snapshot().robot
    wheel_distance = 0.5 * (r.left_wheel_angle_rad + r.right_wheel_angle_rad) * RADIUS
    assert wheel_distance > 0.4
    assert r.x_m == pytest.approx(wheel_distance, rel=0.03)
    assert abs(r.y_m) < 0.005
    assert abs(r.heading_rad) < 0.01
    assert r.left_wheel_speed_rad_s == pytest.approx(wheel_speed_rad_s(LEFT_MOTOR, 1.9), rel=1e-3)
    assert r.right_wheel_speed_rad_s == pytest.approx(r.left_wheel_speed_rad_s, rel=1e-3)


def test_straight_drive_respects_start_pose() -> None:
    start = Pose2D(x_m=1.0, y_m=-0.5, heading_rad=math.pi / 2)
    world = World(WorldConfig(robot_start=start))
    world.set_motor_pulses(*matched_pulses(1.8))
    run(world, 1.0)
    r = world.snapshot().robot
    assert r.x_m == pytest.approx(1.0, abs=0.005)
    assert r.y_m > -0.5 + 0.1
    assert r.heading_rad == pytest.approx(math.pi / 2, abs=0.01)


def test_opposite_pulses_turn_in_place_with_slip() -> None:
    world = World()
    omega = wheel_speed_rad_s(LEFT_MOTOR, 1.2)  # reverse
    world.set_motor_pulses(1.2, pulse_for_wheel_speed_ms(RIGHT_MOTOR, -omega))
    run(world, 1.0)
    r = world.snapshot().robot
    assert math.hypot(r.x_m, r.y_m) < 0.02
    assert r.heading_unwrapped_rad > 3.0  # turned left (CCW)
    implied = (r.right_wheel_angle_rad - r.left_wheel_angle_rad) * RADIUS / MINI_WHEGS.track_width_m
    # The wheel-legs slip when turning in place: less rotation than the wheels imply.
    assert r.heading_unwrapped_rad < 0.97 * implied
    assert r.heading_unwrapped_rad > 0.5 * implied


@pytest.mark.parametrize(
    ("left_ms", "right_ms"), [(1.55, 1.55), (1.48, 1.46), (1.62, 1.65), (1.5, 1.6)]
)
def test_pulses_inside_the_dead_zones_do_not_move(left_ms: float, right_ms: float) -> None:
    world = World()
    world.set_motor_pulses(left_ms, right_ms)
    run(world, 1.0)
    r = world.snapshot().robot
    assert (r.x_m, r.y_m, r.heading_rad) == (0.0, 0.0, 0.0)
    assert (r.left_wheel_angle_rad, r.right_wheel_angle_rad) == (0.0, 0.0)


def test_right_motor_is_slower_so_equal_pulses_curve_right() -> None:
    world = World()
    world.set_motor_pulses(1.9, 1.9)
    run(world, 1.5)
    r = world.snapshot().robot
    assert r.right_wheel_speed_rad_s < r.left_wheel_speed_rad_s
    assert r.right_wheel_angle_rad < r.left_wheel_angle_rad
    assert r.heading_rad < -0.1
    assert r.y_m < -0.01
    assert r.x_m > 0.1


def test_wheel_speed_follows_target_with_first_order_lag() -> None:
    world = World()
    world.set_motor_pulses(2.0, 2.0)
    world.step(0.05)  # one time constant
    r = world.snapshot().robot
    assert r.left_wheel_speed_rad_s == pytest.approx(20.0 * (1 - math.exp(-1)), rel=0.01)
    assert r.right_wheel_speed_rad_s == pytest.approx(17.0 * (1 - math.exp(-1)), rel=0.01)


def test_robot_pushes_the_ball() -> None:
    world = World(WorldConfig(ball=BallConfig(x_m=0.3, y_m=0.0)))
    world.set_motor_pulses(*matched_pulses(1.85))
    run(world, 2.5)
    snap = world.snapshot()
    assert snap.ball is not None
    assert snap.robot.x_m > 0.3
    assert snap.ball.x_m > 0.5
    assert snap.ball.x_m > snap.robot.x_m + 0.05 + snap.ball.radius_m - 0.005
    assert abs(snap.ball.y_m) < 0.05


def test_ball_rolls_and_slows_down_and_can_be_placed() -> None:
    world = World(WorldConfig(ball=BallConfig(x_m=0.5, y_m=0.0)))
    world.set_ball_velocity(0.0, 0.5)
    run(world, 0.5)
    ball = world.snapshot().ball
    assert ball is not None
    assert 0.1 < ball.y_m < 0.25
    assert 0.0 < ball.vy_m_s < 0.5
    run(world, 5.0)
    ball = world.snapshot().ball
    assert ball is not None
    assert ball.vy_m_s == 0.0  # rolling resistance stopped it
    world.place_ball(-1.0, 2.0)
    ball = world.snapshot().ball
    assert ball is not None
    assert (ball.x_m, ball.y_m, ball.vx_m_s, ball.vy_m_s) == (-1.0, 2.0, 0.0, 0.0)


def test_ball_hooks_need_a_ball() -> None:
    with pytest.raises(RuntimeError):
        World().place_ball(0.0, 0.0)


def test_walls_stop_the_robot() -> None:
    world = World(WorldConfig(arena=Arena(x_min_m=-0.5, x_max_m=0.3, y_min_m=-0.5, y_max_m=0.5)))
    world.set_motor_pulses(*matched_pulses(1.9))
    run(world, 2.0)
    r = world.snapshot().robot
    assert r.x_m < 0.3 - MINI_WHEGS.length_m / 2 + 0.005
    assert r.x_m > 0.3 - MINI_WHEGS.length_m / 2 - 0.02
    # The wheels kept turning: odometry from the wheels would overestimate the distance.
    assert r.left_wheel_angle_rad * RADIUS > 0.5


def test_step_time_hooks_and_snapshot() -> None:
    world = World()
    calls: list[float] = []
    remove = world.add_step_hook(lambda w, dt: calls.append(dt))
    first = world.snapshot()
    world.step(0.005)  # not a multiple of the 2 ms substep
    world.step(0.0)
    remove()
    world.step(0.01)
    assert world.time_s == pytest.approx(0.015)
    assert calls == [0.005, 0.0]
    snap = world.snapshot()
    assert snap is not first
    assert snap.step_count == 3
    assert first.time_s == 0.0
    with pytest.raises(dataclasses.FrozenInstanceError):
        snap.robot.x_m = 1.0  # type: ignore[misc]
    with pytest.raises(ValueError):
        world.step(-0.1)
    with pytest.raises(ValueError):
        world.set_motor_pulses(float("nan"), 1.5)


def test_wrap_angle() -> None:
    assert wrap_angle(3 * math.pi / 2) == pytest.approx(-math.pi / 2)
    assert wrap_angle(-math.pi) == pytest.approx(-math.pi)
    assert wrap_angle(0.25) == pytest.approx(0.25)
