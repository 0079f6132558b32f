"""The robot's body as data: the robot file's ``body`` section (issue 49).

One declaration the simulator (the world's robot), the odometry, the PWM mapping and the
encoders all read: the footprint and mass, the drive (skid steering on four wheel-legs, or two
wheels on an axle with a caster), the track and the wheels, each motor's top speed and dead
zone, the encoders' counts. A robot file without ``body`` gets :data:`DEFAULT_BODY`, the
thesis's Mini-WHEGS; the numbers below are its only statement in the code.

What spans fields (a track wider than the body, a dead zone outside the pulse range, a mount
outside the footprint) is checked by :func:`body_problems` and :func:`mount_problems`, whose
answers name the field the robot file's loader reports at its line.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from typing import Annotated, Any, ClassVar, Literal

import msgspec

__all__ = ["DEFAULT_BODY", "MOUNT_FIELDS", "BodyPart", "BodySpec", "EncoderSpec", "MotorSpec",
           "MotorsSpec", "body_problems", "mount_problems"]

Length = Annotated[float, msgspec.Meta(gt=0.0, le=10.0, description="metres, > 0")]
Offset = Annotated[float, msgspec.Meta(ge=-10.0, le=10.0, description="metres, body frame")]
Pulse = Annotated[float, msgspec.Meta(ge=0.5, le=2.5, description="milliseconds")]

FULL_REVERSE_MS = 1.0
FULL_FORWARD_MS = 2.0
"""The pulse range every motor is driven over (the thesis's servo-style PWM)."""


class BodyPart(msgspec.Struct, kw_only=True, forbid_unknown_fields=True, omit_defaults=True):
    """Base of the body's types: as the robot file's (``robotfile.Spec``, which stands above
    this module), keyword-only, unknown keys refused, told by ``what``."""

    what: ClassVar[str] = "it"
    lists: ClassVar[Mapping[str, str]] = {}


class MotorSpec(BodyPart):
    """One motor's measured characteristic: the pulse at which it stands still, the dead zone
    around it, and the wheel speed it reaches at full forward / reverse."""

    what: ClassVar[str] = "a motor"

    max_wheel_speed_rad_s: Annotated[float, msgspec.Meta(gt=0.0, le=1000.0)]
    dead_zone_ms: tuple[Pulse, Pulse]
    """Closed interval ``[lo, hi]`` of pulses for which the wheel does not turn."""
    zero_ms: Pulse = 1.55
    """The pulse at which the motor stands still (the thesis measured 1.55, not 1.5)."""


class MotorsSpec(BodyPart):
    """The two drive motors (the thesis's right one is slower, with a larger dead zone)."""

    what: ClassVar[str] = "`motors`"

    left: MotorSpec = msgspec.field(default_factory=lambda: MotorSpec(
        max_wheel_speed_rad_s=20.0, dead_zone_ms=(1.48, 1.62)))
    right: MotorSpec = msgspec.field(default_factory=lambda: MotorSpec(
        max_wheel_speed_rad_s=17.0, dead_zone_ms=(1.46, 1.65)))


class EncoderSpec(BodyPart):
    """One quadrature encoder per drive motor."""

    what: ClassVar[str] = "`encoders`"

    counts_per_rev: Annotated[int, msgspec.Meta(ge=1, le=1_000_000)] = 1024
    edges_per_count: Literal[1, 2, 4] = 4
    """Edges of the A/B lines per count (4: both edges of both lines)."""


class BodySpec(BodyPart):
    """The robot's body (SI, REP-103 body frame: x forward, y left, origin at the footprint's
    centre). Every default is the thesis's Mini-WHEGS."""

    what: ClassVar[str] = "`body`"

    length_m: Length = 0.10
    width_m: Length = 0.07
    height_m: Length = 0.05
    """How tall the shell is (what other robots' cameras and range finders see)."""
    mass_kg: Annotated[float, msgspec.Meta(gt=0.0, le=1000.0)] = 0.15
    drive: Literal["skid-steer", "differential"] = "skid-steer"
    """``skid-steer``: four wheel-legs, a left and a right pair, each pair on one motor (the
    Mini-WHEGS); ``differential``: two drive wheels on one axle and a free caster."""
    track_m: Length = 0.06
    """Between the left and right wheel contact lines."""
    wheelbase_m: Length = 0.06
    """Skid steering: between the front and rear wheel-leg contacts of a side."""
    axle_x_m: Offset = 0.0
    """Differential drive: where the drive wheels' axle is, ahead of the centre."""
    caster_x_m: Offset | None = None
    """Differential drive: where the caster is (it carries weight, steers nothing)."""
    wheel_radius_m: Length = 0.02
    effective_track_m: Length | None = 0.42
    """The track the odometry integrates the heading with: a skid-steer body yaws only a
    fraction of what its wheels' difference implies (``python -m components.encoders.calibrate``
    fits it; the Mini-WHEGS's is 0.42 m for a 6 cm track). ``null``: the physical
    ``track_m`` (a drive that does not skid)."""
    motor_time_constant_s: Annotated[float, msgspec.Meta(gt=0.0, le=10.0)] = 0.05
    """First-order lag of a wheel's speed behind its motor's target."""
    turn_gain: Annotated[float, msgspec.Meta(gt=0.0, le=1.0)] = 1.0
    """The share of the wheels' speed difference a ``turn`` of 100 commands: the HAL's way of
    making the thesis's turn commands turn a body about as fast as they turn the Mini-WHEGS
    (whose skid steering yaws at ≈ 14 % of its wheels' difference; a differential drive at
    all of it, so a camera with the same latency would overshoot the ball)."""
    motors: MotorsSpec = msgspec.field(default_factory=MotorsSpec)
    encoders: EncoderSpec = msgspec.field(default_factory=EncoderSpec)

    @property
    def odometry_track_m(self) -> float:
        """What the odometry divides the wheels' difference by (see ``effective_track_m``)."""
        return self.track_m if self.effective_track_m is None else self.effective_track_m

    @property
    def edges_per_rev(self) -> int:
        return self.encoders.counts_per_rev * self.encoders.edges_per_count

    @property
    def top_speed_m_s(self) -> float:
        """Forward speed at ``speed`` 100: both wheels at the slower motor's top speed."""
        slower = min(self.motors.left.max_wheel_speed_rad_s,
                     self.motors.right.max_wheel_speed_rad_s)
        return slower * self.wheel_radius_m


DEFAULT_BODY = BodySpec()
"""The thesis's Mini-WHEGS: < 4 in long, 100–200 g, skid steering, 1024-count encoders."""


def body_problems(body: BodySpec) -> Iterator[tuple[tuple[str, ...], str]]:
    """What is wrong with ``body`` as a whole: ``(path within body, message)`` each."""
    if body.track_m > body.width_m:
        yield ("track_m",), (f"track_m {body.track_m:g} m is wider than the body "
                             f"(width_m {body.width_m:g} m): the wheels must fit under it")
    if body.drive == "skid-steer":
        if body.wheelbase_m > body.length_m:
            yield ("wheelbase_m",), (f"wheelbase_m {body.wheelbase_m:g} m is longer than the "
                                     f"body (length_m {body.length_m:g} m)")
        if body.caster_x_m is not None:
            yield ("caster_x_m",), "a skid-steer body has no caster: drive: differential"
    else:
        if body.caster_x_m is None:
            yield ("drive",), "a differential drive needs caster_x_m (where its caster is)"
        elif abs(body.caster_x_m) > body.length_m / 2:
            yield ("caster_x_m",), _outside("the caster", body.caster_x_m, None, body)
        elif body.caster_x_m * body.axle_x_m > 0 or body.caster_x_m == body.axle_x_m:
            # The centre of mass (the origin) must lie between the axle and the caster, or
            # the body tips over (and the weights on them would come out negative).
            yield ("caster_x_m",), (f"caster_x_m {body.caster_x_m:g} m and axle_x_m "
                                    f"{body.axle_x_m:g} m must lie on either side of the "
                                    f"centre (x = 0), or the body tips over")
        if abs(body.axle_x_m) > body.length_m / 2:
            yield ("axle_x_m",), _outside("the axle", body.axle_x_m, None, body)
    for side in ("left", "right"):
        motor: MotorSpec = getattr(body.motors, side)
        lo, hi = motor.dead_zone_ms
        if not FULL_REVERSE_MS < lo <= motor.zero_ms <= hi < FULL_FORWARD_MS:
            yield ("motors", side), (
                f"the {side} motor needs {FULL_REVERSE_MS:g} < dead zone lo <= zero_ms <= "
                f"dead zone hi < {FULL_FORWARD_MS:g} ms, got dead_zone_ms [{lo:g}, {hi:g}] "
                f"and zero_ms {motor.zero_ms:g}")


MOUNT_FIELDS = ("x_m", "y_m")
"""A device whose factory takes both is mounted on the body (a camera, a range finder, any
plug-in's): where, in the body frame, is checked against the footprint."""


def mount_problems(params: Mapping[str, Any], body: BodySpec) -> Iterator[tuple[str, str]]:
    """What is wrong with a device's mount (its ``x_m``, ``y_m``) on ``body``: ``(param,
    message)`` each. A mount on the footprint's edge is on the body (a bumper, a lens)."""
    x, y = float(params["x_m"]), float(params["y_m"])
    if abs(x) > body.length_m / 2 + 1e-9 or abs(y) > body.width_m / 2 + 1e-9:
        yield ("x_m" if abs(x) > body.length_m / 2 + 1e-9 else "y_m"), \
            _outside("the mount", x, y, body)


def _outside(what: str, x: float, y: float | None, body: BodySpec) -> str:
    where = f"x {x:g} m" if y is None else f"({x:g}, {y:g}) m"
    return (f"{what} at {where} is outside the body's footprint "
            f"(x ±{body.length_m / 2:g} m, y ±{body.width_m / 2:g} m)")

