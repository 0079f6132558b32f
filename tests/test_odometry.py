"""Dead reckoning in components.encoders.odometry."""

from __future__ import annotations

import math

import pytest

from components.encoders.odometry import OdometryPose, WheelOdometry, wrap_angle
from components.miniwhegs import MINI_WHEGS, MiniWhegsGeometry

R = MINI_WHEGS.wheel_radius_m
TRACK = MINI_WHEGS.track_width_m


def approx_pose(pose: OdometryPose, x_m: float, y_m: float, heading_rad: float) -> None:
    assert pose.x_m == pytest.approx(x_m, abs=1e-12)
    assert pose.y_m == pytest.approx(y_m, abs=1e-12)
    assert pose.heading_rad == pytest.approx(heading_rad, abs=1e-12)


@pytest.mark.parametrize("revolutions", [1, 3, 10])
def test_straight_run(revolutions: int) -> None:
    odo = WheelOdometry()
    angle = 2 * math.pi * revolutions
    pose = odo.update(angle, angle)
    approx_pose(pose, revolutions * 2 * math.pi * R, 0.0, 0.0)


def test_straight_run_backwards_in_steps() -> None:
    odo = WheelOdometry()
    for _ in range(100):
        odo.update(-0.1, -0.1)
    approx_pose(odo.pose, -10 * R, 0.0, 0.0)


@pytest.mark.parametrize("wheel_angle", [0.3, 1.0, -0.7])
def test_turn_in_place(wheel_angle: float) -> None:
    odo = WheelOdometry()
    pose = odo.update(-wheel_angle, wheel_angle)
    approx_pose(pose, 0.0, 0.0, 2 * R * wheel_angle / TRACK)


def test_turn_in_place_wraps_heading() -> None:
    odo = WheelOdometry()
    # a half turn and a bit more to the left: heading wraps to just above -π
    wheel_angle = (math.pi + 0.1) * TRACK / (2 * R)
    pose = odo.update(-wheel_angle, wheel_angle)
    approx_pose(pose, 0.0, 0.0, -math.pi + 0.1)
    # exactly half a turn reads +π, never -π
    odo.reset()
    half = math.pi * TRACK / (2 * R)
    assert odo.update(half, -half).heading_rad == pytest.approx(math.pi)


def test_quarter_circle_left() -> None:
    """Centre path radius 0.1 m, turning left a quarter circle, by hand.

    Centre radius ρ = 0.1, track 0.06: left wheel path ρ − 0.03 = 0.07 m, right ρ + 0.03 =
    0.13 m, each over an angle π/2. Wheel angles: 0.07·π/2 / 0.02 and 0.13·π/2 / 0.02.
    Start at the origin facing +x; the circle's centre is at (0, 0.1); after a quarter turn
    the robot is at (0.1, 0.1) facing +y.
    """
    rho = 0.1
    d_left = (rho - TRACK / 2) * (math.pi / 2) / R
    d_right = (rho + TRACK / 2) * (math.pi / 2) / R
    assert d_left == pytest.approx(5.497787143782138)
    assert d_right == pytest.approx(10.210176124166829)
    pose = WheelOdometry().update(d_left, d_right)
    approx_pose(pose, 0.1, 0.1, math.pi / 2)


def test_quarter_circle_backwards_from_a_pose() -> None:
    """Reversing with the left wheel turning more: the heading still grows by π/2.

    Start at (1, 2) facing +y. The centre travels ds = −0.2·π/2 while the heading changes by
    +π/2, so the signed radius is −0.2 m: the centre of the circle is 0.2 m to the robot's
    right, at (1.2, 2.0). A quarter turn about it takes the robot to (1.2, 1.8), facing −x.
    """
    odo = WheelOdometry(pose=OdometryPose(x_m=1.0, y_m=2.0, heading_rad=math.pi / 2))
    rho = 0.2
    d_left = -(rho + TRACK / 2) * (math.pi / 2) / R
    d_right = -(rho - TRACK / 2) * (math.pi / 2) / R
    pose = odo.update(d_left, d_right)
    approx_pose(pose, 1.2, 1.8, math.pi)


@pytest.mark.parametrize("steps", [2, 10, 1000])
def test_many_small_steps_equal_one_big_step(steps: int) -> None:
    d_left, d_right = 7.0, 11.0
    big = WheelOdometry().update(d_left, d_right)
    odo = WheelOdometry()
    for _ in range(steps):
        odo.update(d_left / steps, d_right / steps)
    assert odo.pose.x_m == pytest.approx(big.x_m, abs=1e-9)
    assert odo.pose.y_m == pytest.approx(big.y_m, abs=1e-9)
    assert odo.pose.heading_rad == pytest.approx(big.heading_rad, abs=1e-9)


def test_full_circle_returns_home() -> None:
    rho = 0.15
    d_left = (rho - TRACK / 2) * 2 * math.pi / R
    d_right = (rho + TRACK / 2) * 2 * math.pi / R
    odo = WheelOdometry()
    for _ in range(37):
        odo.update(d_left / 37, d_right / 37)
    approx_pose(odo.pose, 0.0, 0.0, 0.0)


def test_other_geometry_and_reset() -> None:
    odo = WheelOdometry(MiniWhegsGeometry(wheel_radius_m=0.05, track_width_m=0.2))
    odo.update(2.0, 2.0)
    approx_pose(odo.pose, 0.1, 0.0, 0.0)
    odo.reset(OdometryPose(x_m=1.0, y_m=-1.0, heading_rad=3 * math.pi))
    approx_pose(odo.pose, 1.0, -1.0, math.pi)
    odo.reset()
    approx_pose(odo.pose, 0.0, 0.0, 0.0)


def test_wrap_angle() -> None:
    assert wrap_angle(0.0) == 0.0
    assert wrap_angle(math.pi) == pytest.approx(math.pi)
    assert wrap_angle(-math.pi) == pytest.approx(math.pi)
    assert wrap_angle(3 * math.pi / 2) == pytest.approx(-math.pi / 2)
    assert wrap_angle(-5 * math.pi / 2) == pytest.approx(-math.pi / 2)


def test_bad_input_rejected() -> None:
    with pytest.raises(ValueError, match="finite"):
        WheelOdometry().update(math.nan, 0.0)
    with pytest.raises(ValueError, match="finite"):
        WheelOdometry().reset(OdometryPose(x_m=math.inf))
    with pytest.raises(ValueError, match="positive"):
        WheelOdometry(MiniWhegsGeometry(track_width_m=0.0))


def test_effective_track_scales_the_heading_only() -> None:
    """A skid-steer robot's odometry integrates the heading with its effective track: the
    same wheel rotations turn it track/effective times less and drive it as far."""
    physical, effective = WheelOdometry(), WheelOdometry(effective_track_m=0.42)
    assert effective.track_m == 0.42 and physical.track_m == MINI_WHEGS.track_width_m
    for odo in (physical, effective):
        odo.update(-1.0, 1.0)
    assert effective.pose.heading_rad == pytest.approx(
        wrap_angle(physical.pose.heading_rad * MINI_WHEGS.track_width_m / 0.42))
    a, b = WheelOdometry(), WheelOdometry(effective_track_m=0.42)
    assert a.update(2.0, 2.0) == b.update(2.0, 2.0)
    for bad in (0.0, -0.1, math.nan):
        with pytest.raises(ValueError, match="effective_track_m"):
            WheelOdometry(effective_track_m=bad)


def test_unwrapped_heading_counts_full_turns() -> None:
    """Three and a half turns to the left, then one back: the pose's heading wraps, the
    unwrapped heading counts every turn (an error past 180° must stay visible)."""
    odo = WheelOdometry(pose=OdometryPose(heading_rad=0.5))
    quarter = (math.pi / 2) * TRACK / (2 * R)  # wheel angle for a quarter turn in place
    for _ in range(14):
        odo.update(-quarter, quarter)
    assert odo.heading_unwrapped_rad == pytest.approx(0.5 + 7 * math.pi)
    assert odo.pose.heading_rad == pytest.approx(wrap_angle(0.5 + 7 * math.pi))
    for _ in range(4):
        odo.update(quarter, -quarter)
    assert odo.heading_unwrapped_rad == pytest.approx(0.5 + 5 * math.pi)
    odo.reset(OdometryPose(heading_rad=3 * math.pi))
    assert odo.heading_unwrapped_rad == pytest.approx(3 * math.pi)
    assert odo.pose.heading_rad == pytest.approx(math.pi)
