"""Speed/turn mixing, per-motor calibration and the motor model in components.motors.pwm."""

from __future__ import annotations

import itertools
import math

import pytest

from components.motors.pwm import (
    COMMON_MAX_WHEEL_SPEED_RAD_S,
    DEFAULT_LEFT_CALIBRATION,
    DEFAULT_RIGHT_CALIBRATION,
    LEFT_MOTOR,
    MEASURED_ZERO_MS,
    RIGHT_MOTOR,
    MotorCalibration,
    MotorCharacteristic,
    PwmConfig,
    calibration_for,
    clamp_drive,
    mix,
    pulse_for_wheel_speed_ms,
    pulse_widths,
    wheel_speed_rad_s,
)

LEFT = DEFAULT_LEFT_CALIBRATION
RIGHT = DEFAULT_RIGHT_CALIBRATION


# --- mixing -------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("speed", "turn", "expected"),
    [
        (0, 0, (0.0, 0.0)),
        (40, 0, (40.0, 40.0)),
        (-40, 0, (-40.0, -40.0)),
        (0, 30, (-30.0, 30.0)),  # +turn = left: left wheel back, right wheel forward
        (0, -30, (30.0, -30.0)),
        (40, 30, (10.0, 70.0)),
        (50, 50, (0.0, 100.0)),
    ],
)
def test_mix_without_saturation(speed: float, turn: float, expected: tuple[float, float]) -> None:
    assert mix(speed, turn) == pytest.approx(expected)


@pytest.mark.parametrize(("speed", "turn"), [(100, 100), (80, 60), (-90, 40), (10, -100)])
def test_mix_scales_both_sides_and_keeps_the_curvature(speed: float, turn: float) -> None:
    raw_left, raw_right = speed - turn, speed + turn
    left, right = mix(speed, turn)
    assert max(abs(left), abs(right)) == pytest.approx(100.0)
    # same factor on both sides: the ratio (and so the turning radius) is unchanged
    scale = 100.0 / max(abs(raw_left), abs(raw_right))
    assert left == pytest.approx(raw_left * scale)
    assert right == pytest.approx(raw_right * scale)


def test_mix_full_speed_and_full_turn() -> None:
    assert mix(100, 100) == pytest.approx((0.0, 100.0))
    assert mix(-100, 100) == pytest.approx((-100.0, 0.0))


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_mix_rejects_non_finite(bad: float) -> None:
    with pytest.raises(ValueError, match="finite"):
        mix(bad, 0)
    with pytest.raises(ValueError, match="finite"):
        mix(0, bad)


@pytest.mark.parametrize(("speed", "turn"), [(100.5, 0), (0, -101), (-200, 0)])
def test_mix_rejects_out_of_range(speed: float, turn: float) -> None:
    with pytest.raises(ValueError, match="within"):
        mix(speed, turn)


def test_clamp_drive() -> None:
    assert clamp_drive(150, -250) == (100.0, -100.0)
    assert clamp_drive(-30.5, 20) == (-30.5, 20.0)
    with pytest.raises(ValueError, match="speed"):
        clamp_drive(math.nan, 0)
    with pytest.raises(ValueError, match="turn"):
        clamp_drive(0, math.inf)


# --- motor model ----------------------------------------------------------------------------------


def test_motor_model_matches_the_measured_characteristic() -> None:
    assert wheel_speed_rad_s(LEFT_MOTOR, MEASURED_ZERO_MS) == 0.0
    for p in (1.48, 1.50, 1.62):
        assert wheel_speed_rad_s(LEFT_MOTOR, p) == 0.0
    for p in (1.46, 1.5, 1.65):
        assert wheel_speed_rad_s(RIGHT_MOTOR, p) == 0.0
    assert wheel_speed_rad_s(LEFT_MOTOR, 2.0) == pytest.approx(20.0)
    assert wheel_speed_rad_s(LEFT_MOTOR, 1.0) == pytest.approx(-20.0)
    assert wheel_speed_rad_s(RIGHT_MOTOR, 2.0) == pytest.approx(17.0)
    assert wheel_speed_rad_s(RIGHT_MOTOR, 1.0) == pytest.approx(-17.0)
    assert wheel_speed_rad_s(LEFT_MOTOR, 1.81) == pytest.approx(20.0 * 0.19 / 0.38)
    assert wheel_speed_rad_s(RIGHT_MOTOR, 1.23) == pytest.approx(-17.0 * 0.23 / 0.46)
    # beyond the PWM range the motor saturates
    assert wheel_speed_rad_s(LEFT_MOTOR, 2.5) == pytest.approx(20.0)
    # the right motor is the slower one, with the wider dead zone
    assert RIGHT_MOTOR.max_wheel_speed_rad_s < LEFT_MOTOR.max_wheel_speed_rad_s
    assert RIGHT_MOTOR.dead_zone_ms[0] < LEFT_MOTOR.dead_zone_ms[0]
    assert RIGHT_MOTOR.dead_zone_ms[1] > LEFT_MOTOR.dead_zone_ms[1]
    assert COMMON_MAX_WHEEL_SPEED_RAD_S == 17.0


@pytest.mark.parametrize("motor", [LEFT_MOTOR, RIGHT_MOTOR])
@pytest.mark.parametrize("speed", [-17.0, -5.0, -0.01, 0.0, 0.01, 3.0, 17.0])
def test_pulse_for_wheel_speed_inverts_the_model(motor: MotorCharacteristic, speed: float) -> None:
    assert wheel_speed_rad_s(motor, pulse_for_wheel_speed_ms(motor, speed)) == pytest.approx(speed)


def test_pulse_for_wheel_speed_rejects_unreachable_speed() -> None:
    with pytest.raises(ValueError, match="exceeds"):
        pulse_for_wheel_speed_ms(RIGHT_MOTOR, 18.0)


def test_bad_characteristic_rejected() -> None:
    with pytest.raises(ValueError, match="dead zone"):
        MotorCharacteristic(dead_zone_ms=(1.6, 1.5), max_wheel_speed_rad_s=10.0)
    with pytest.raises(ValueError, match="positive"):
        MotorCharacteristic(dead_zone_ms=(1.48, 1.62), max_wheel_speed_rad_s=0.0)


# --- calibration: dead zone and asymmetry ---------------------------------------------------


def test_zero_command_gives_the_measured_zero() -> None:
    assert LEFT.pulse_ms(0) == MEASURED_ZERO_MS == 1.55
    assert RIGHT.pulse_ms(0) == 1.55
    assert LEFT.zero_ms == RIGHT.zero_ms == 1.55


@pytest.mark.parametrize("u", [1.0, 0.5, 1e-6])
def test_small_forward_command_jumps_over_the_dead_zone(u: float) -> None:
    assert LEFT.pulse_ms(u) > 1.62
    assert RIGHT.pulse_ms(u) > 1.65
    assert wheel_speed_rad_s(LEFT_MOTOR, LEFT.pulse_ms(u)) > 0.0
    assert wheel_speed_rad_s(RIGHT_MOTOR, RIGHT.pulse_ms(u)) > 0.0


@pytest.mark.parametrize("u", [-1.0, -0.5, -1e-6])
def test_small_reverse_command_jumps_over_the_dead_zone(u: float) -> None:
    assert LEFT.pulse_ms(u) < 1.48
    assert RIGHT.pulse_ms(u) < 1.46
    assert wheel_speed_rad_s(LEFT_MOTOR, LEFT.pulse_ms(u)) < 0.0
    assert wheel_speed_rad_s(RIGHT_MOTOR, RIGHT.pulse_ms(u)) < 0.0


def test_one_percent_is_just_outside_the_dead_zone() -> None:
    assert LEFT.pulse_ms(1) == pytest.approx(1.62 + 0.01 * (1.943 - 1.62))
    assert RIGHT.pulse_ms(-1) == pytest.approx(1.46 - 0.01 * 0.46)


@pytest.mark.parametrize("u", [-100, -73.5, -40, -10, -1, 1, 5, 25, 50, 66.6, 90, 100])
def test_both_sides_reach_the_same_wheel_speed(u: float) -> None:
    left_speed = wheel_speed_rad_s(LEFT_MOTOR, LEFT.pulse_ms(u))
    right_speed = wheel_speed_rad_s(RIGHT_MOTOR, RIGHT.pulse_ms(u))
    assert left_speed == pytest.approx(right_speed, rel=0.01)
    assert left_speed == pytest.approx(COMMON_MAX_WHEEL_SPEED_RAD_S * u / 100, rel=0.01)


def test_uncompensated_motors_would_differ() -> None:
    """The same pulse on both motors does not give the same speed — why calibration exists."""
    for p in (1.3, 1.7, 1.9):
        assert wheel_speed_rad_s(LEFT_MOTOR, p) != pytest.approx(
            wheel_speed_rad_s(RIGHT_MOTOR, p), rel=0.01
        )


def test_calibration_is_monotonic() -> None:
    for cal in (LEFT, RIGHT):
        pulses = [cal.pulse_ms(u / 4) for u in range(-400, 401)]
        assert all(b >= a for a, b in itertools.pairwise(pulses))


# --- limits ---------------------------------------------------------------------------------------


def test_outputs_stay_within_pwm_limits() -> None:
    for cal in (LEFT, RIGHT):
        for u in (-1000.0, -100.0, -100.0001, 100.0, 100.0001, 1e9):
            assert 1.0 <= cal.pulse_ms(u) <= 2.0
    assert RIGHT.pulse_ms(100) == pytest.approx(2.0)
    assert RIGHT.pulse_ms(-100) == pytest.approx(1.0)
    # the faster left motor needs less than full pulse to match the right one
    assert LEFT.pulse_ms(100) == pytest.approx(1.62 + 0.85 * 0.38)
    assert LEFT.pulse_ms(-100) == pytest.approx(1.48 - 0.85 * 0.48)
    assert LEFT.pulse_ms(250) == LEFT.pulse_ms(100)


def test_calibration_rejects_nan() -> None:
    with pytest.raises(ValueError, match="finite"):
        LEFT.pulse_ms(math.nan)
    with pytest.raises(ValueError, match="finite"):
        pulse_widths(math.nan, 0)


def test_pulse_widths() -> None:
    stop = pulse_widths(0, 0)
    assert (stop.left_ms, stop.right_ms) == (1.55, 1.55)
    assert (stop.left_direction, stop.right_direction) == (0, 0)

    cmd = pulse_widths(40, 30)
    assert (cmd.left_u, cmd.right_u) == pytest.approx((10.0, 70.0))
    assert cmd.left_ms == pytest.approx(LEFT.pulse_ms(10))
    assert cmd.right_ms == pytest.approx(RIGHT.pulse_ms(70))
    assert (cmd.left_direction, cmd.right_direction) == (1, 1)

    spin = pulse_widths(0, 50)  # turn left in place
    assert (spin.left_direction, spin.right_direction) == (-1, 1)
    assert spin.left_ms < 1.48
    assert spin.right_ms > 1.65

    back = pulse_widths(-100, -100, left=LEFT, right=RIGHT)
    assert (back.left_u, back.right_u) == pytest.approx((0.0, -100.0))
    assert (back.left_direction, back.right_direction) == (0, -1)
    assert back.right_ms == pytest.approx(1.0)


# --- table validation -----------------------------------------------------------------------------


def test_custom_table_interpolates() -> None:
    cal = MotorCalibration(points=((-100, 1.0), (0, 1.5), (50, 1.6), (100, 2.0)))
    assert cal.pulse_ms(0) == 1.5
    assert cal.pulse_ms(-50) == pytest.approx(1.25)
    assert cal.pulse_ms(25) == pytest.approx(1.55)
    assert cal.pulse_ms(75) == pytest.approx(1.8)
    # without breakaway pulses the table is continuous through zero
    assert cal.pulse_ms(1e-9) == pytest.approx(1.5)


@pytest.mark.parametrize(
    ("points", "breakaway", "match"),
    [
        (((-100, 1.0), (100, 2.0)), None, "at least 3"),
        (((-100, 1.0), (0, 1.5), (50, 1.7)), None, "span"),
        (((-90, 1.0), (0, 1.5), (100, 2.0)), None, "span"),
        (((-100, 1.0), (0, 1.5), (0, 1.6), (100, 2.0)), None, "strictly increasing"),
        (((-100, 1.0), (20, 1.5), (10, 1.6), (100, 2.0)), None, "strictly increasing"),
        (((-100, 1.0), (-10, 1.5), (10, 1.6), (100, 2.0)), None, "u = 0"),
        (((-100, 1.0), (0, 1.5), (50, 1.4), (100, 2.0)), None, "decrease"),
        (((-100, 1.0), (0, 1.55), (100, 2.0)), (1.6, 1.62), "decrease"),
        (((-100, 0.9), (0, 1.5), (100, 2.0)), None, "PWM limits"),
        (((-100, 1.0), (0, 1.5), (100, 2.1)), None, "PWM limits"),
        (((-100, 1.0), (0, math.nan), (100, 2.0)), None, "finite"),
    ],
)
def test_bad_tables_rejected(
    points: tuple[tuple[float, float], ...],
    breakaway: tuple[float, float] | None,
    match: str,
) -> None:
    with pytest.raises(ValueError, match=match):
        MotorCalibration(points=points, breakaway_ms=breakaway)


def test_table_checked_against_its_own_pwm_config() -> None:
    narrow = PwmConfig(min_ms=1.1, max_ms=1.9)
    with pytest.raises(ValueError, match="PWM limits"):
        calibration_for(RIGHT_MOTOR, 17.0, config=narrow)


def test_calibration_for_rejects_unreachable_common_max() -> None:
    with pytest.raises(ValueError, match="common_max_rad_s"):
        calibration_for(RIGHT_MOTOR, 20.0)
    with pytest.raises(ValueError, match="common_max_rad_s"):
        calibration_for(LEFT_MOTOR, -1.0)


def test_bad_pwm_config_rejected() -> None:
    assert PwmConfig().init_ms == 1.6
    with pytest.raises(ValueError, match="min_ms"):
        PwmConfig(min_ms=2.0, max_ms=1.0)
    with pytest.raises(ValueError, match="init_ms"):
        PwmConfig(init_ms=2.5)
    with pytest.raises(ValueError, match="finite"):
        PwmConfig(period_ms=math.inf)
