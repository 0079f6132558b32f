"""Speed/turn → per-motor PWM pulse widths for a body's motors (pure logic, no I/O).

The thesis drives the robot with two numbers, ``speed`` and ``turn``, each −100…+100
(+speed forward, +turn = turn left, REP-103). :func:`mix` turns them into a wheel command ``u``
per side (−100…+100), and a per-motor :class:`MotorCalibration` turns each ``u`` into the high
time of the 20 ms PWM period. The two real motors differ (DESIGN.md §3): measured zero ≈1.55 ms
instead of the nominal 1.5 ms, a dead zone around it, and the right motor is slower with a larger
dead zone. The default calibrations invert the measured characteristic of each motor
(:func:`wheel_speed_rad_s`, which the simulator also uses) so that the same ``u`` gives the same
wheel speed on both sides and any nonzero ``u`` moves the wheel.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

# One limit for speed, turn and the wheel command ``u``: the UBF's, re-exported here.
from ubf_async.assembly.body import (
    DEFAULT_BODY,
    FULL_FORWARD_MS,
    FULL_REVERSE_MS,
    BodySpec,
    MotorSpec,
)
from ubf_async.core.action import COMMAND_LIMIT as COMMAND_LIMIT
from ubf_async.core.action import clamp_command

__all__ = ["COMMON_MAX_WHEEL_SPEED_RAD_S", "DEFAULT_LEFT_CALIBRATION", "DEFAULT_PWM",
           "DEFAULT_RIGHT_CALIBRATION", "FULL_FORWARD_MS", "FULL_REVERSE_MS", "HOLD_PERIODS",
           "LEFT_MOTOR", "MEASURED_ZERO_MS", "RIGHT_MOTOR", "MotorCalibration",
           "MotorCharacteristic", "PulseCommand", "PwmConfig", "body_calibrations",
           "calibration_for", "characteristic_of", "clamp_drive", "hold_s", "mix",
           "pulse_for_wheel_speed_ms", "pulse_widths", "wheel_speed_rad_s"]

MEASURED_ZERO_MS = DEFAULT_BODY.motors.left.zero_ms
"""Pulse at which both real motors stand still (the nominal zero is 1.5 ms)."""


def _require_finite(**values: float) -> None:
    for name, value in values.items():
        if not math.isfinite(value):
            raise ValueError(f"{name} must be a finite number, got {value!r}")


def clamp_drive(speed: float, turn: float) -> tuple[float, float]:
    """Clamp a finite speed/turn pair to ±100; NaN or ±inf raise ``ValueError``.

    The component calls this on what behaviours send before :func:`mix`, which refuses
    out-of-range input so that a bug upstream is not silently absorbed there.
    """
    _require_finite(speed=speed, turn=turn)  # says which of the two is bad
    return clamp_command(float(speed)), clamp_command(float(turn))


def mix(speed: float, turn: float) -> tuple[float, float]:
    """Skid-steer mixing: ``(left, right) = (speed − turn, speed + turn)``.

    If either side would exceed ±100 both are scaled down by the same factor, which keeps their
    ratio and hence the curvature of the path (only the pace drops). Raises ``ValueError`` for
    non-finite input or input outside ±100 (use :func:`clamp_drive` first).
    """
    _require_finite(speed=speed, turn=turn)
    for name, value in (("speed", speed), ("turn", turn)):
        if abs(value) > COMMAND_LIMIT:
            raise ValueError(f"{name} must be within ±{COMMAND_LIMIT:g}, got {value!r}")
    left = float(speed) - float(turn)
    right = float(speed) + float(turn)
    largest = max(abs(left), abs(right))
    if largest > COMMAND_LIMIT:
        scale = COMMAND_LIMIT / largest
        left *= scale
        right *= scale
    return left, right


@dataclass(frozen=True, slots=True, kw_only=True)
class PwmConfig:
    """The PWM signal both motors receive (thesis values)."""

    period_ms: float = 20.0
    min_ms: float = 1.0
    """Full reverse; no pulse is ever shorter."""
    max_ms: float = 2.0
    """Full forward; no pulse is ever longer."""
    nominal_zero_ms: float = 1.5
    """The datasheet zero; the real motors stop at :data:`MEASURED_ZERO_MS` instead."""
    init_ms: float = 1.6
    """Pulse sent once at start-up to arm the motor drivers."""

    def __post_init__(self) -> None:
        _require_finite(
            period_ms=self.period_ms,
            min_ms=self.min_ms,
            max_ms=self.max_ms,
            nominal_zero_ms=self.nominal_zero_ms,
            init_ms=self.init_ms,
        )
        if not 0.0 < self.min_ms < self.nominal_zero_ms < self.max_ms <= self.period_ms:
            raise ValueError(
                "PwmConfig needs 0 < min_ms < nominal_zero_ms < max_ms <= period_ms, got "
                f"min_ms={self.min_ms}, nominal_zero_ms={self.nominal_zero_ms}, "
                f"max_ms={self.max_ms}, period_ms={self.period_ms}"
            )
        if not self.min_ms <= self.init_ms <= self.max_ms:
            raise ValueError(
                f"PwmConfig.init_ms={self.init_ms} must lie within "
                f"[min_ms={self.min_ms}, max_ms={self.max_ms}]"
            )


DEFAULT_PWM = PwmConfig()

HOLD_PERIODS = 2
"""Whole PWM periods the init pulse and the stop pulse stay on the pins before the next pulse
(after the init pulse) or before the pins are released (after the stop pulse).

A servo-style speed controller measures one pulse per period, and a duty cycle changed in the
middle of a period can make that period's pulse neither the old width nor the new one: two
periods guarantee at least one whole period of the new width. Hold times are wall time (the
pins do not run on simulated time)."""


def hold_s(period_ms: float) -> float:
    """Seconds that :data:`HOLD_PERIODS` periods of ``period_ms`` last."""
    return HOLD_PERIODS * period_ms / 1000.0


@dataclass(frozen=True, slots=True, kw_only=True)
class MotorCharacteristic:
    """Measured steady-state behaviour of one motor: pulse width → wheel speed.

    See :func:`wheel_speed_rad_s` for the model these numbers parameterise.
    """

    dead_zone_ms: tuple[float, float]
    """Closed interval ``[lo, hi]`` of pulses for which the wheel does not turn."""
    max_wheel_speed_rad_s: float
    """Wheel speed at full forward / full reverse."""
    zero_ms: float = MEASURED_ZERO_MS
    full_reverse_ms: float = FULL_REVERSE_MS
    full_forward_ms: float = FULL_FORWARD_MS

    def __post_init__(self) -> None:
        lo, hi = self.dead_zone_ms
        _require_finite(
            dead_zone_lo_ms=lo,
            dead_zone_hi_ms=hi,
            max_wheel_speed_rad_s=self.max_wheel_speed_rad_s,
            zero_ms=self.zero_ms,
            full_reverse_ms=self.full_reverse_ms,
            full_forward_ms=self.full_forward_ms,
        )
        if not self.full_reverse_ms < lo <= self.zero_ms <= hi < self.full_forward_ms:
            raise ValueError(
                "MotorCharacteristic needs full_reverse_ms < dead zone lo <= zero_ms <= "
                f"dead zone hi < full_forward_ms, got full_reverse_ms={self.full_reverse_ms}, "
                f"dead_zone_ms={self.dead_zone_ms}, zero_ms={self.zero_ms}, "
                f"full_forward_ms={self.full_forward_ms}"
            )
        if self.max_wheel_speed_rad_s <= 0.0:
            raise ValueError(
                f"max_wheel_speed_rad_s must be positive, got {self.max_wheel_speed_rad_s}"
            )


def characteristic_of(motor: MotorSpec) -> MotorCharacteristic:
    """A robot file's motor (``body.motors.left`` …) as the model :func:`wheel_speed_rad_s`
    reads."""
    return MotorCharacteristic(dead_zone_ms=motor.dead_zone_ms, zero_ms=motor.zero_ms,
                               max_wheel_speed_rad_s=motor.max_wheel_speed_rad_s)


LEFT_MOTOR = characteristic_of(DEFAULT_BODY.motors.left)
RIGHT_MOTOR = characteristic_of(DEFAULT_BODY.motors.right)
"""The Mini-WHEGS's: the right motor is slower and has the larger dead zone (thesis
measurement)."""


def wheel_speed_rad_s(characteristic: MotorCharacteristic, pulse_ms: float) -> float:
    """Steady wheel speed a motor reaches for ``pulse_ms`` (the single source of truth).

    0 inside the dead zone ``[lo, hi]``; linear from 0 at ``hi`` to ``+max`` at full forward,
    and from 0 at ``lo`` to ``−max`` at full reverse. Pulses beyond full forward / full reverse
    saturate at ``±max``.
    """
    _require_finite(pulse_ms=pulse_ms)
    c = characteristic
    lo, hi = c.dead_zone_ms
    p = min(max(float(pulse_ms), c.full_reverse_ms), c.full_forward_ms)
    if p > hi:
        return c.max_wheel_speed_rad_s * (p - hi) / (c.full_forward_ms - hi)
    if p < lo:
        return -c.max_wheel_speed_rad_s * (lo - p) / (lo - c.full_reverse_ms)
    return 0.0


def pulse_for_wheel_speed_ms(characteristic: MotorCharacteristic, speed_rad_s: float) -> float:
    """Inverse of :func:`wheel_speed_rad_s`: the pulse that gives ``speed_rad_s``.

    0 maps to the measured zero; a nonzero speed maps to the dead-zone edge on its side plus the
    linear part, so it always lies strictly outside the dead zone. Raises ``ValueError`` when the
    motor cannot reach the speed.
    """
    _require_finite(speed_rad_s=speed_rad_s)
    c = characteristic
    if abs(speed_rad_s) > c.max_wheel_speed_rad_s:
        raise ValueError(
            f"speed {speed_rad_s} rad/s exceeds the motor's maximum {c.max_wheel_speed_rad_s}"
        )
    lo, hi = c.dead_zone_ms
    fraction = abs(speed_rad_s) / c.max_wheel_speed_rad_s
    if speed_rad_s > 0.0:
        return hi + fraction * (c.full_forward_ms - hi)
    if speed_rad_s < 0.0:
        return lo - fraction * (lo - c.full_reverse_ms)
    return c.zero_ms


@dataclass(frozen=True, slots=True, kw_only=True)
class MotorCalibration:
    """Per-motor table from wheel command ``u`` (−100…+100) to pulse width (ms).

    ``points`` are ``(u, pulse_ms)`` pairs with strictly increasing ``u`` from −100 to +100 and
    non-decreasing pulses; the entry at ``u = 0`` is the motor's measured zero. Between points
    the pulse is interpolated linearly. ``breakaway_ms = (reverse_ms, forward_ms)``, when given,
    is the pulse a nonzero ``u`` starts from as it leaves 0 on each side (the dead-zone edges):
    the table then jumps over the dead zone, so ``u = 0`` stops the motor and any ``u ≠ 0``
    turns it. Every pulse must lie within the :class:`PwmConfig` limits and outputs are clipped
    to them as well.
    """

    points: tuple[tuple[float, float], ...]
    breakaway_ms: tuple[float, float] | None = None
    config: PwmConfig = DEFAULT_PWM
    _neg: tuple[np.ndarray, np.ndarray] = field(init=False, repr=False, compare=False)
    _pos: tuple[np.ndarray, np.ndarray] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        points = tuple((float(u), float(ms)) for u, ms in self.points)
        object.__setattr__(self, "points", points)
        if len(points) < 3:
            raise ValueError(f"a calibration table needs at least 3 points, got {len(points)}")
        us = np.array([u for u, _ in points])
        ms = np.array([p for _, p in points])
        if not (np.all(np.isfinite(us)) and np.all(np.isfinite(ms))):
            raise ValueError(f"calibration points must be finite, got {points!r}")
        if us[0] != -COMMAND_LIMIT or us[-1] != COMMAND_LIMIT:
            raise ValueError(
                f"calibration table must span u = -100 … +100, got {us[0]:g} … {us[-1]:g}"
            )
        if np.any(np.diff(us) <= 0.0):
            raise ValueError(f"calibration u values must be strictly increasing, got {us.tolist()}")
        zero_index = np.flatnonzero(us == 0.0)
        if zero_index.size != 1:
            raise ValueError("calibration table must contain a point at u = 0 (the zero pulse)")
        z = int(zero_index[0])
        zero_ms = float(ms[z])
        if self.breakaway_ms is None:
            rev_ms, fwd_ms = zero_ms, zero_ms
        else:
            rev_ms, fwd_ms = (float(v) for v in self.breakaway_ms)
            object.__setattr__(self, "breakaway_ms", (rev_ms, fwd_ms))
            _require_finite(breakaway_reverse_ms=rev_ms, breakaway_forward_ms=fwd_ms)
        neg_u = np.append(us[:z], 0.0)
        neg_ms = np.append(ms[:z], rev_ms)
        pos_u = np.insert(us[z + 1 :], 0, 0.0)
        pos_ms = np.insert(ms[z + 1 :], 0, fwd_ms)
        ordered = np.concatenate([neg_ms, [zero_ms], pos_ms])
        if np.any(np.diff(ordered) < 0.0):
            raise ValueError(
                "calibration pulses must not decrease as u increases (including the breakaway "
                f"pulses around u = 0), got {ordered.tolist()}"
            )
        cfg = self.config
        if ordered[0] < cfg.min_ms or ordered[-1] > cfg.max_ms:
            raise ValueError(
                f"calibration pulses {ordered[0]:g} … {ordered[-1]:g} ms exceed the PWM limits "
                f"[{cfg.min_ms:g}, {cfg.max_ms:g}] ms"
            )
        object.__setattr__(self, "_neg", (neg_u, neg_ms))
        object.__setattr__(self, "_pos", (pos_u, pos_ms))

    @property
    def zero_ms(self) -> float:
        """Pulse for ``u = 0`` (the motor's measured zero)."""
        return next(ms for u, ms in self.points if u == 0.0)

    def pulse_ms(self, u: float) -> float:
        """Pulse width for wheel command ``u``; ``u`` beyond ±100 is treated as ±100.

        Raises ``ValueError`` for NaN or ±inf.
        """
        _require_finite(u=u)
        if u == 0.0:
            return self.zero_ms
        xs, ys = self._pos if u > 0.0 else self._neg
        pulse = float(np.interp(u, xs, ys))
        return min(max(pulse, self.config.min_ms), self.config.max_ms)


def calibration_for(
    characteristic: MotorCharacteristic,
    common_max_rad_s: float,
    *,
    config: PwmConfig = DEFAULT_PWM,
    points_per_side: int = 4,
) -> MotorCalibration:
    """Calibration table that makes ``u`` mean "``u`` % of ``common_max_rad_s``" on this motor.

    Built from :func:`pulse_for_wheel_speed_ms`: ``u = ±100`` reaches ``±common_max_rad_s``
    (pass the slower motor's maximum so both sides can match), ``u = 0`` is the measured zero,
    and the breakaway pulses are the dead-zone edges so any nonzero ``u`` moves the wheel.
    """
    _require_finite(common_max_rad_s=common_max_rad_s)
    if not 0.0 < common_max_rad_s <= characteristic.max_wheel_speed_rad_s:
        raise ValueError(
            f"common_max_rad_s must be in (0, {characteristic.max_wheel_speed_rad_s}] for this "
            f"motor, got {common_max_rad_s}"
        )
    if points_per_side < 1:
        raise ValueError(f"points_per_side must be at least 1, got {points_per_side}")
    us = np.linspace(-COMMAND_LIMIT, COMMAND_LIMIT, 2 * points_per_side + 1)
    points = tuple(
        (float(u), pulse_for_wheel_speed_ms(characteristic, common_max_rad_s * u / COMMAND_LIMIT))
        for u in us
    )
    return MotorCalibration(
        points=points, breakaway_ms=characteristic.dead_zone_ms, config=config
    )


def body_calibrations(body: BodySpec) -> tuple[MotorCalibration, MotorCalibration]:
    """The (left, right) calibrations that make ``u`` mean the same wheel speed on both of
    ``body``'s motors: ``u = ±100`` is the slower motor's top speed."""
    left, right = characteristic_of(body.motors.left), characteristic_of(body.motors.right)
    common = min(left.max_wheel_speed_rad_s, right.max_wheel_speed_rad_s)
    return calibration_for(left, common), calibration_for(right, common)


COMMON_MAX_WHEEL_SPEED_RAD_S = min(
    LEFT_MOTOR.max_wheel_speed_rad_s, RIGHT_MOTOR.max_wheel_speed_rad_s
)
"""Fastest wheel speed both Mini-WHEGS motors can reach: what ``u = ±100`` means on either
side."""
DEFAULT_LEFT_CALIBRATION, DEFAULT_RIGHT_CALIBRATION = body_calibrations(DEFAULT_BODY)


def _direction(u: float) -> int:
    return (u > 0.0) - (u < 0.0)


@dataclass(frozen=True, slots=True, kw_only=True)
class PulseCommand:
    """What one speed/turn command becomes: pulses, wheel commands and wheel directions."""

    left_ms: float
    right_ms: float
    left_u: float
    right_u: float
    left_direction: int
    """−1, 0 or +1: the commanded direction of the left wheel (the encoders use it)."""
    right_direction: int


def pulse_widths(
    speed: float,
    turn: float,
    *,
    left: MotorCalibration = DEFAULT_LEFT_CALIBRATION,
    right: MotorCalibration = DEFAULT_RIGHT_CALIBRATION,
) -> PulseCommand:
    """Mix ``speed``/``turn`` (each within ±100) and calibrate each side to a pulse width."""
    left_u, right_u = mix(speed, turn)
    return PulseCommand(
        left_ms=left.pulse_ms(left_u),
        right_ms=right.pulse_ms(right_u),
        left_u=left_u,
        right_u=right_u,
        left_direction=_direction(left_u),
        right_direction=_direction(right_u),
    )

