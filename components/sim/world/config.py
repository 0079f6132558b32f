"""A simulated world before it runs: what a :class:`~components.sim.world.physics.World` is
built from.

Frozen, validated value types only — no physics, no pymunk: the robot's start pose
(:class:`WorldPose`) and its mechanical and ground-contact model (:class:`RobotConfig`), the ball
(:class:`BallConfig`), walls and arenas (:class:`Wall`, :class:`Arena`), box obstacles
(:class:`BoxObstacle`), distractors (:class:`Distractor`), the lighting (:class:`Lighting`), and
:class:`WorldConfig`, which gathers them with the seed and the substep. Also the default
colours and the small checks the types validate their fields with. Walls, boxes and lighting
also travel in every :class:`~components.sim.world.snapshot.WorldSnapshot`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

from components.miniwhegs import MINI_WHEGS, MiniWhegsGeometry
from components.motors.pwm import LEFT_MOTOR, RIGHT_MOTOR, MotorCharacteristic, characteristic_of
from ubf_async.assembly.body import DEFAULT_BODY, BodySpec

__all__ = ["BALL_DIAMETER_M", "BALL_PINK", "BOX_COLOR", "CAMERA_X_M", "ORANGE", "WALL_COLOR",
           "Arena", "BallConfig", "BoxObstacle", "Color", "Distractor", "DistractorKind",
           "Lighting", "RobotConfig", "Wall", "WorldConfig", "WorldPose", "box_corners",
           "require_finite", "require_positive"]

Color = tuple[int, int, int]
"""An 8-bit RGB colour."""

BALL_PINK: Color = (236, 72, 132)
"""Base (fully lit, unshaded) colour of the thesis's pink ball."""
WALL_COLOR: Color = (200, 194, 160)
"""Default wall colour: a neutral beige that never passes the pink rule."""
BOX_COLOR: Color = (180, 168, 128)
"""Default box-obstacle colour (cardboard), also neutral."""
ORANGE: Color = (255, 140, 0)
"""A typical distractor colour (an orange ball) that must never read as pink."""

BALL_DIAMETER_M = 0.065


def require_finite(**values: float) -> None:
    """Raise ``ValueError`` naming the first of ``values`` that is not a finite number."""
    for name, value in values.items():
        if not math.isfinite(value):
            raise ValueError(f"{name} must be a finite number, got {value!r}")


def require_positive(**values: float) -> None:
    """Raise ``ValueError`` naming the first of ``values`` that is not a positive finite
    number."""
    for name, value in values.items():
        if not (math.isfinite(value) and value > 0.0):
            raise ValueError(f"{name} must be a positive finite number, got {value!r}")


@dataclass(frozen=True, slots=True, kw_only=True)
class WorldPose:
    """A planar pose: position (m) and heading (rad, CCW from +x)."""

    x_m: float = 0.0
    y_m: float = 0.0
    heading_rad: float = 0.0

    def __post_init__(self) -> None:
        require_finite(x_m=self.x_m, y_m=self.y_m, heading_rad=self.heading_rad)


@dataclass(frozen=True, slots=True, kw_only=True)
class BallConfig:
    """The pink ball: light, rolls with damping, can be pushed by the robot."""

    x_m: float
    y_m: float
    radius_m: float = BALL_DIAMETER_M / 2
    mass_kg: float = 0.02
    color: Color = BALL_PINK
    linear_damping_per_s: float = 0.5
    """Viscous part of the rolling loss: deceleration ``= damping · v``."""
    rolling_resistance: float = 0.02
    """Coulomb part of the rolling loss: deceleration ``= coefficient · g``."""
    elasticity: float = 0.5

    def __post_init__(self) -> None:
        require_finite(x_m=self.x_m, y_m=self.y_m)
        require_positive(radius_m=self.radius_m, mass_kg=self.mass_kg)
        if self.linear_damping_per_s < 0.0 or self.rolling_resistance < 0.0:
            raise ValueError("ball damping and rolling resistance must be >= 0")


@dataclass(frozen=True, slots=True, kw_only=True)
class Wall:
    """A vertical, infinitely thin wall standing on the segment (x1, y1)–(x2, y2)."""

    x1_m: float
    y1_m: float
    x2_m: float
    y2_m: float
    height_m: float = 0.30
    color: Color = WALL_COLOR

    def __post_init__(self) -> None:
        require_finite(x1_m=self.x1_m, y1_m=self.y1_m, x2_m=self.x2_m, y2_m=self.y2_m)
        require_positive(height_m=self.height_m)
        if (self.x1_m, self.y1_m) == (self.x2_m, self.y2_m):
            raise ValueError("a wall needs two distinct end points")

    @property
    def length_m(self) -> float:
        return math.hypot(self.x2_m - self.x1_m, self.y2_m - self.y1_m)


@dataclass(frozen=True, slots=True, kw_only=True)
class Arena:
    """A rectangular arena: four walls around ``[x_min, x_max] × [y_min, y_max]``."""

    x_min_m: float = -1.5
    y_min_m: float = -1.5
    x_max_m: float = 1.5
    y_max_m: float = 1.5
    height_m: float = 0.30
    color: Color = WALL_COLOR

    def __post_init__(self) -> None:
        if not (self.x_min_m < self.x_max_m and self.y_min_m < self.y_max_m):
            raise ValueError("Arena needs x_min < x_max and y_min < y_max")

    def walls(self) -> tuple[Wall, ...]:
        x0, y0, x1, y1 = self.x_min_m, self.y_min_m, self.x_max_m, self.y_max_m
        corners = ((x0, y0), (x1, y0), (x1, y1), (x0, y1))
        return tuple(
            Wall(
                x1_m=a[0], y1_m=a[1], x2_m=b[0], y2_m=b[1],
                height_m=self.height_m, color=self.color,
            )
            for a, b in zip(corners, corners[1:] + corners[:1], strict=True)
        )


@dataclass(frozen=True, slots=True, kw_only=True)
class BoxObstacle:
    """A static box: centre, size along its own x (length) and y (width), yaw, height."""

    x_m: float
    y_m: float
    length_m: float
    width_m: float
    height_m: float = 0.10
    yaw_rad: float = 0.0
    color: Color = BOX_COLOR

    def __post_init__(self) -> None:
        require_finite(x_m=self.x_m, y_m=self.y_m, yaw_rad=self.yaw_rad)
        require_positive(length_m=self.length_m, width_m=self.width_m, height_m=self.height_m)

    def corners(self) -> tuple[tuple[float, float], ...]:
        """Footprint corners, counter-clockwise, in the world frame."""
        return box_corners(
            self.x_m, self.y_m, self.yaw_rad, self.length_m, self.width_m
        )


DistractorKind = Literal["cylinder", "sphere", "box"]

@dataclass(frozen=True, slots=True, kw_only=True)
class Distractor:
    """A coloured object that is not the ball (e.g. an orange ball or a red can).

    ``cylinder`` and ``sphere`` use ``radius_m``; ``box`` uses ``length_m``/``width_m``/``yaw_rad``.
    ``height_m`` defaults to the diameter for a sphere and 0.10 m otherwise. A ``movable``
    distractor is a dynamic body (it rolls like the ball); otherwise it is static.
    """

    kind: DistractorKind
    x_m: float
    y_m: float
    color: Color = ORANGE
    radius_m: float = BALL_DIAMETER_M / 2
    length_m: float = 0.05
    width_m: float = 0.05
    height_m: float | None = None
    yaw_rad: float = 0.0
    movable: bool = False
    mass_kg: float = 0.05

    def __post_init__(self) -> None:
        if self.kind not in ("cylinder", "sphere", "box"):
            raise ValueError(f"unknown distractor kind {self.kind!r}")
        require_finite(x_m=self.x_m, y_m=self.y_m, yaw_rad=self.yaw_rad)
        require_positive(
            radius_m=self.radius_m, length_m=self.length_m, width_m=self.width_m,
            mass_kg=self.mass_kg,
        )
        if self.height_m is not None:
            require_positive(height_m=self.height_m)

    @property
    def effective_height_m(self) -> float:
        if self.height_m is not None:
            return self.height_m
        return 2.0 * self.radius_m if self.kind == "sphere" else 0.10


@dataclass(frozen=True, slots=True, kw_only=True)
class Lighting:
    """Scene lighting, relative to the calibrated nominal (1.0, 1.0).

    ``brightness`` multiplies the exposure of every rendered object (not the far background);
    ``glare`` scales the angular size of the specular glare patch on shiny spheres (0 = none).
    """

    brightness: float = 1.0
    glare: float = 1.0

    def __post_init__(self) -> None:
        require_positive(brightness=self.brightness)
        if not (math.isfinite(self.glare) and self.glare >= 0.0):
            raise ValueError(f"glare must be >= 0, got {self.glare!r}")


CAMERA_X_M = 0.05
"""Where the Mini-WHEGS's camera sits ahead of its centre (the camera device's default)."""


@dataclass(frozen=True, slots=True, kw_only=True)
class RobotConfig:
    """Mechanical and ground-contact model of a robot: by default the Mini-WHEGS; any body a
    robot file declares through :meth:`from_body`."""

    geometry: MiniWhegsGeometry = MINI_WHEGS
    wheelbase_m: float = DEFAULT_BODY.wheelbase_m
    """Skid steering: distance between the front and rear wheel-leg contacts of a side."""
    drive: Literal["skid-steer", "differential"] = DEFAULT_BODY.drive
    """``skid-steer``: four wheel-leg contacts (the Mini-WHEGS); ``differential``: two drive
    wheels on an axle at ``axle_x_m`` and a free caster at ``caster_x_m``, which carries its
    share of the weight and no horizontal force."""
    axle_x_m: float = DEFAULT_BODY.axle_x_m
    caster_x_m: float | None = DEFAULT_BODY.caster_x_m
    height_m: float = DEFAULT_BODY.height_m
    """The shell's height, as other robots' cameras and range finders see it."""
    camera_x_m: float = CAMERA_X_M
    """Where the robot's (first) camera sits ahead of its centre: scenarios place objects
    "from the camera", and the summary measures the ball's distance from it."""
    left_motor: MotorCharacteristic = LEFT_MOTOR
    right_motor: MotorCharacteristic = RIGHT_MOTOR
    motor_time_constant_s: float = DEFAULT_BODY.motor_time_constant_s
    """First-order lag of the wheel speed behind the motor's target speed."""
    mu_longitudinal: float = 0.8
    """Friction coefficient along the body: a contact pushes with at most ``μ·m·g/4`` (so
    ``μ·m·g/2`` per track)."""
    mu_lateral: float = 0.8
    """Friction coefficient across the body: a contact resists sideways sliding with at most
    ``μ·m·g/4``. Together with ``mu_longitudinal`` it spans the friction ellipse; the floor's
    Coulomb friction is the same both ways, what differs is the slip it takes (below)."""
    longitudinal_slip_m_s: float = 0.06
    """Slip between the wheel-legs' surface speed and the ground at which the traction reaches
    its limit (linear below). Soft: the spoke tips scuff and dig in before they push fully. The
    larger it is relative to ``lateral_slip_m_s`` the more of a wheel speed difference is lost to
    slip instead of yaw (see :mod:`components.sim.world.physics` for the yaw fraction κ)."""
    lateral_slip_m_s: float = 0.01
    """Sideways sliding speed of a contact at which its lateral friction reaches the limit
    (linear below). Stiff: a spoke dragged sideways bites at once. This grip along the robot's
    length is what resists the yaw of a skid turn."""
    body_friction: float = 0.4
    """Friction of the robot's shell against walls, ball and obstacles."""

    def __post_init__(self) -> None:
        require_positive(
            wheelbase_m=self.wheelbase_m,
            motor_time_constant_s=self.motor_time_constant_s,
            mu_longitudinal=self.mu_longitudinal,
            mu_lateral=self.mu_lateral,
            longitudinal_slip_m_s=self.longitudinal_slip_m_s,
            lateral_slip_m_s=self.lateral_slip_m_s,
        )

    @classmethod
    def from_body(cls, body: BodySpec, *, camera_x_m: float | None = None) -> RobotConfig:
        """The model of a robot file's ``body`` (the ground contact's defaults kept), its
        first camera ``camera_x_m`` ahead of its centre (``None``: the Mini-WHEGS's)."""
        return cls(geometry=MiniWhegsGeometry.of(body), wheelbase_m=body.wheelbase_m,
                   drive=body.drive, axle_x_m=body.axle_x_m, caster_x_m=body.caster_x_m,
                   height_m=body.height_m,
                   camera_x_m=CAMERA_X_M if camera_x_m is None else camera_x_m,
                   left_motor=characteristic_of(body.motors.left),
                   right_motor=characteristic_of(body.motors.right),
                   motor_time_constant_s=body.motor_time_constant_s)

    def wheel_contacts(self, weight_n: float) -> tuple[tuple[float, float, int, float], ...]:
        """Where the drive touches the floor: ``(x, y, side, load)`` per contact in the body
        frame (side 0 = left, +y), the load its share of ``weight_n``. Skid steering: four
        wheel-legs with a quarter each; differential: the two wheels share what the caster
        does not carry (lever rule about the centre)."""
        half_track = self.geometry.track_width_m / 2
        if self.drive == "differential" and self.caster_x_m is not None:
            x, caster = self.axle_x_m, self.caster_x_m
            share = weight_n * (-caster / (x - caster)) / 2
            return ((x, half_track, 0, share), (x, -half_track, 1, share))
        half_base = self.wheelbase_m / 2
        share = weight_n / 4
        return ((half_base, half_track, 0, share), (-half_base, half_track, 0, share),
                (half_base, -half_track, 1, share), (-half_base, -half_track, 1, share))

    @property
    def yaw_fraction(self) -> float:
        """κ: the steady yaw rate as a fraction of the kinematic ``(v_R − v_L)/track`` that the
        linearised contact model predicts (see :mod:`components.sim.world.physics`); 1 for a
        differential drive, whose wheels need not slide sideways to turn."""
        if self.drive == "differential":
            return 1.0
        a2 = (self.wheelbase_m / 2) ** 2
        b2 = (self.geometry.track_width_m / 2) ** 2
        c_long = self.mu_longitudinal / self.longitudinal_slip_m_s
        c_lat = self.mu_lateral / self.lateral_slip_m_s
        return c_long * b2 / (c_long * b2 + c_lat * a2)


@dataclass(frozen=True, slots=True, kw_only=True)
class WorldConfig:
    """Everything needed to build a :class:`~components.sim.world.physics.World`; ``seed``
    drives all randomness."""

    robot_start: WorldPose = field(default_factory=WorldPose)
    robot: RobotConfig = field(default_factory=RobotConfig)
    more_robots: tuple[WorldPose, ...] = ()
    """Start poses of further robots of the same make in this world (a fleet): robot ``i``
    (1, 2, …) starts at ``more_robots[i - 1]``; robot 0 at ``robot_start``. Each sees the
    others in its camera and IR (:meth:`~components.sim.world.physics.World.snapshot_for`)."""
    ball: BallConfig | None = None
    arena: Arena | None = None
    walls: tuple[Wall, ...] = ()
    boxes: tuple[BoxObstacle, ...] = ()
    distractors: tuple[Distractor, ...] = ()
    lighting: Lighting = field(default_factory=Lighting)
    seed: int = 0
    substep_s: float = 0.002
    """Largest physics substep; ``step(dt)`` splits dt into equal substeps no longer than it."""
    gravity_m_s2: float = 9.81
    """Only used for the friction caps (the 2-D world itself has no gravity)."""

    def __post_init__(self) -> None:
        require_positive(substep_s=self.substep_s, gravity_m_s2=self.gravity_m_s2)

    def all_walls(self) -> tuple[Wall, ...]:
        arena = self.arena.walls() if self.arena is not None else ()
        return arena + tuple(self.walls)


def box_corners(
    x: float, y: float, yaw: float, length: float, width: float
) -> tuple[tuple[float, float], ...]:
    """The footprint corners of a box centred at (x, y), turned by ``yaw``, counter-clockwise."""
    c, s = math.cos(yaw), math.sin(yaw)
    hl, hw = length / 2, width / 2
    local = ((hl, -hw), (hl, hw), (-hl, hw), (-hl, -hw))
    return tuple((x + c * lx - s * ly, y + s * lx + c * ly) for lx, ly in local)

