"""The pymunk world: skid-steer drive, motor characteristics, ball, walls, snapshots."""

from __future__ import annotations

import dataclasses
import math
import time

import pytest

from components.miniwhegs import MINI_WHEGS
from components.motors.pwm import (
    LEFT_MOTOR,
    RIGHT_MOTOR,
    pulse_for_wheel_speed_ms,
    pulse_widths,
    wheel_speed_rad_s,
)
from components.sim.world.config import Arena, BallConfig, RobotConfig, WorldConfig, WorldPose
from components.sim.world.physics import World, wrap_angle
from components.sim.world.steady_drive import (
    THESIS_DRIVE_COMMANDS,
    SteadyDrive,
    drive_table,
    format_drive_table,
    steady_drive,
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
    start = WorldPose(x_m=1.0, y_m=-0.5, heading_rad=math.pi / 2)
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
    assert r.heading_unwrapped_rad > 0.5  # turned left (CCW), not stuck
    implied = (r.right_wheel_angle_rad - r.left_wheel_angle_rad) * RADIUS / MINI_WHEGS.track_width_m
    # Skid steering: the wheel-legs slip a lot when turning in place, so the body turns much
    # less than the wheels imply (the encoders would overestimate the rotation several times).
    assert r.heading_unwrapped_rad < 0.3 * implied
    assert r.heading_unwrapped_rad > 0.08 * implied


def _thesis_drive(speed: float, turn: float) -> SteadyDrive:
    pulses = pulse_widths(speed, turn)
    return steady_drive(pulses.left_ms, pulses.right_ms)


@pytest.mark.parametrize(
    ("speed", "turn", "low_deg_s", "high_deg_s"),
    [
        (40, 30, 20, 40),  # chase, inner bin
        (40, 60, 40, 80),  # chase, outer bin
        (10, 80, 60, 120),  # search: "a slow, tight circle"
        (0, 100, 30, 180),  # full in-place turn
    ],
)
def test_skid_steer_yaw_rates_of_the_thesis_commands(
    speed: float, turn: float, low_deg_s: float, high_deg_s: float
) -> None:
    left = _thesis_drive(speed, turn)
    assert low_deg_s < left.yaw_rate_deg_s < high_deg_s  # +turn = left = CCW
    # Most of the wheel speed difference is lost to slip, not to yaw.
    assert left.yaw_rate_rad_s < 0.3 * left.kinematic_yaw_rate_rad_s
    right = _thesis_drive(speed, -turn)
    assert right.yaw_rate_deg_s == pytest.approx(-left.yaw_rate_deg_s, rel=0.05)
    # The forward pace is what the wheels give (the turn does not stall the robot).
    assert left.forward_speed_m_s == pytest.approx(left.kinematic_speed_m_s, abs=0.01)
    if speed > 0:
        assert left.forward_speed_m_s > 0.02
    else:
        assert abs(left.forward_speed_m_s) < 0.005


def test_search_drives_a_slow_tight_circle() -> None:
    search = _thesis_drive(10, 80)
    assert 0.01 < search.forward_speed_m_s < 0.06
    assert 0.01 < search.turn_radius_m < 0.06  # a few cm
    chase = _thesis_drive(40, 30)
    assert 0.15 < chase.turn_radius_m < 0.6


def test_straight_chase_drive_does_not_yaw_or_slip() -> None:
    chase = _thesis_drive(40, 0)
    assert abs(chase.yaw_rate_deg_s) < 0.5
    assert chase.forward_speed_m_s == pytest.approx(chase.kinematic_speed_m_s, rel=0.03)


def test_yaw_fraction_predicts_the_measured_turn_rate() -> None:
    rc = RobotConfig()
    assert 0.1 < rc.yaw_fraction < 0.2
    d = _thesis_drive(40, 60)
    assert d.yaw_rate_rad_s / d.kinematic_yaw_rate_rad_s == pytest.approx(
        rc.yaw_fraction, rel=0.1
    )
    # Softer longitudinal slip (or stiffer lateral grip) loses more of the turn.
    soft = dataclasses.replace(rc, longitudinal_slip_m_s=2 * rc.longitudinal_slip_m_s)
    assert soft.yaw_fraction < rc.yaw_fraction
    pulses = pulse_widths(40, 60)
    slower = steady_drive(pulses.left_ms, pulses.right_ms, robot=soft)
    assert slower.yaw_rate_rad_s < 0.8 * d.yaw_rate_rad_s


def test_drive_table_prints_the_thesis_commands(capsys: pytest.CaptureFixture[str]) -> None:
    rows = drive_table()
    assert [(s, t) for s, t, _ in rows] == list(THESIS_DRIVE_COMMANDS)
    table = format_drive_table(rows)
    with capsys.disabled():
        print("\n" + table)
    assert len(table.splitlines()) == len(rows) + 1


@pytest.mark.parametrize("substep_s", [0.005, 0.02])
def test_ground_contact_is_stable_with_coarse_substeps(substep_s: float) -> None:
    fine = _thesis_drive(10, 80)
    world = World(WorldConfig(substep_s=substep_s))
    pulses = pulse_widths(10, 80)
    world.set_motor_pulses(pulses.left_ms, pulses.right_ms)
    run(world, 2.0, dt=substep_s)
    start = world.snapshot().robot.heading_unwrapped_rad
    run(world, 2.0, dt=substep_s)
    r = world.snapshot().robot
    assert (r.heading_unwrapped_rad - start) / 2.0 == pytest.approx(fine.yaw_rate_rad_s, rel=0.05)
    assert math.hypot(r.vx_m_s, r.vy_m_s) < 0.1


def test_stepping_is_deterministic_and_cheap() -> None:
    def drive() -> tuple[World, float]:
        world = World(WorldConfig(ball=BallConfig(x_m=0.3, y_m=0.05)))
        start = time.process_time()
        for i in range(400):
            if i % 100 == 0:
                pulses = pulse_widths(40, (-60, 30, 80, 0)[i // 100])
                world.set_motor_pulses(pulses.left_ms, pulses.right_ms)
            world.step(0.005)
        return world, (time.process_time() - start) / 400

    a, cpu_per_step = drive()
    b, _ = drive()
    assert a.snapshot().robot == b.snapshot().robot
    assert a.snapshot().ball == b.snapshot().ball
    assert cpu_per_step < 1e-3  # a 5 ms step: well under 1 ms of CPU (≈0.1 ms measured)


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


def test_contacts_name_what_touched_the_robot_and_when() -> None:
    """Nothing touches a robot driving in the open; the box it drives into, the arena's wall
    it is then reversed into, the ball and a hand's push are each named, with the end of the
    last step they touched it in (what the run's summary reports as disturbed periods)."""
    from components.sim.world.config import BoxObstacle, Distractor

    world = World(WorldConfig(
        arena=Arena(x_min_m=-0.3, x_max_m=1.0, y_min_m=-0.5, y_max_m=0.5),
        boxes=(BoxObstacle(x_m=0.4, y_m=0.0, length_m=0.1, width_m=0.3),),
        distractors=(Distractor(kind="sphere", x_m=0.0, y_m=0.3),),
        ball=BallConfig(x_m=0.0, y_m=-0.3)))
    world.set_motor_pulses(*matched_pulses(1.85))
    run(world, 1.0, dt=0.005)
    assert world.contacts() == {}
    run(world, 2.0, dt=0.005)  # nose against the box from ≈ 1.8 s
    assert world.contacts() == {"obstacles[0]": pytest.approx(world.time_s)}
    world.set_motor_pulses(*matched_pulses(1.15))  # full reverse into the arena's wall
    run(world, 4.0, dt=0.005)
    touched = world.contacts()
    assert set(touched) == {"obstacles[0]", "arena"}
    assert touched["arena"] == pytest.approx(world.time_s)
    assert touched["obstacles[0]"] < world.time_s - 2.0  # left the box long ago
    world.set_motor_pulses(*matched_pulses(1.5))
    # Put down beside the (static) orange ball, the pink ball dropped against its other side.
    world.place_robot(WorldPose(x_m=0.0, y_m=0.3 - 0.0325 - 0.035 + 0.002))
    world.place_ball(0.0, 0.3 - 0.0325 - 0.07 - 0.0325 + 0.002)
    world.shift_robot(0.0, 0.0, 0.01)
    run(world, 0.05, dt=0.005)
    touched = world.contacts()
    assert {"distractors[0]", "ball", "push"} <= set(touched)
    assert touched["push"] < world.time_s  # only the step it was shoved in


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


def test_simulated_time_does_not_drift_over_a_long_run() -> None:
    """Time is kept in whole nanoseconds: 36 000 steps of 5 ms are exactly 180 s (a float
    sum is 91 ps short — enough that a clock held at the run's end was never reached)."""
    world = World(WorldConfig(substep_s=0.005))
    for _ in range(36_000):
        world.step(0.005)
    assert world.time_s == 180.0 and world.snapshot().time_s == 180.0


def test_wrap_angle() -> None:
    assert wrap_angle(3 * math.pi / 2) == pytest.approx(-math.pi / 2)
    assert wrap_angle(-math.pi) == pytest.approx(-math.pi)
    assert wrap_angle(0.25) == pytest.approx(0.25)
