"""A top-down 2-D pymunk world with the Mini-WHEGS, a pink ball, walls and obstacles.

Everything is SI and REP-103: x forward/east, y left/north, z up, headings counter-clockwise from
+x. pymunk has no gravity here (we look down on the floor); the ground acts through friction
forces this module computes itself every substep:

* The robot is a ≈10 cm × 7 cm box of 0.15 kg standing on four wheel-leg contacts at
  ``(±wheelbase/2, ±track_width/2)`` in the body frame, each carrying a quarter of its weight.
  Each motor turns the PWM pulse it receives into a target wheel speed with the measured
  characteristic (:func:`components.motors.pwm.wheel_speed_rad_s`); the wheel follows the target
  with a first-order lag. The encoders see the wheel, not the ground, so slip is invisible to
  them.
* Any other body a robot file declares (:meth:`~components.sim.world.config.RobotConfig.from_body`)
  is built the same way from its numbers; a *differential* drive stands on two wheel contacts
  on its axle (their share of the weight by the lever rule) and a caster that carries the rest
  and no horizontal force, so it turns about the axle without sliding sideways.
* Ground contact (skid steering). Each contact slides over the floor with a slip velocity: along
  the body, the ground speed of the contact point minus the wheel-leg's surface speed ``ω·r``;
  across it, the contact point's sideways speed. The floor answers with one Coulomb friction
  force against that slip (a friction ellipse with the semi-axes ``μ_long·m·g/4`` and
  ``μ_lat·m·g/4``), so a contact that slides sideways has less grip left to push with. How much
  slip mobilises the friction differs by direction, and that is what sets the turning rate: a
  three-spoke wheel-leg pushes through one or two spoke tips that scuff and dig in, so traction
  builds up softly (full at ``RobotConfig.longitudinal_slip_m_s``, a few cm/s), while a spoke
  dragged sideways bites almost at once (full at ``RobotConfig.lateral_slip_m_s``, about
  1 cm/s). Below these slips the force grows linearly with the slip, above them it stays
  at the friction limit and turns with the direction of the (scaled) slip.

  Turning therefore costs lateral sliding of the front and rear legs in opposite directions: the
  ground's lateral friction along the robot's length resists the yaw with a turning-resistance
  moment of at most ``μ_lat·m·g·wheelbase/2`` (≈ the classic ``μ_lat·m·g·L/4`` of a skid-steer
  vehicle of length ``L``; ≈70 % of it in an in-place turn), and the tracks must slip hard to
  overcome it. Because both directions saturate along the same scaled slip, the body yaws at a
  nearly constant fraction of the kinematic rate ``(v_R − v_L)/track`` whatever the speeds::

      κ ≈ C_long·b² / (C_long·b² + C_lat·a²),   C = μ / slip,   a = wheelbase/2, b = track/2

  ≈ 0.14 with the defaults (a real skid-steer robot's "effective track width" is the track
  divided by κ). Driving straight needs no slip once the robot is up to speed, so the encoders
  agree with the true distance; an in-place turn slips a lot but still turns. Run
  ``python -m components.sim.world.steady_drive`` to print the steady yaw rates of the thesis's
  commands (:func:`~components.sim.world.steady_drive.steady_drive`); for the defaults:

  ===============  =========  ==========  ==========  ===========
  speed / turn     u (L / R)  yaw °/s     kinematic   forward m/s
  ===============  =========  ==========  ==========  ===========
  +40 / 0          40 / 40    0           0           0.136
  +40 / +30        10 / 70    +28         +195        0.136
  +40 / +60        −20 / 100  +56         +390        0.136
  +10 / +80        −70 / 90   +74         +520        0.034
  0 / +100         −100 / 100 +93         +649        0.000
  ===============  =========  ==========  ==========  ===========

  The contact forces are applied semi-implicitly (each body-frame axis divides its force by
  ``1 + h·k/m`` with ``k`` the contacts' force per unit slip), so the stiff lateral grip stays
  stable at any substep.
* The ball and movable distractors roll with viscous damping plus a rolling resistance.
* Walls are infinitely thin vertical surfaces (pymunk segments of radius 0); box obstacles and
  static distractors are static pymunk shapes.

The world is built from a :class:`~components.sim.world.config.WorldConfig`
(:mod:`components.sim.world.config` holds the scene description and the robot's model,
:class:`~components.sim.world.config.RobotConfig`, whose parameters are named above).

``World.step`` advances the physics in fixed-size substeps; after every step the world replaces
its immutable :class:`~components.sim.world.snapshot.WorldSnapshot`, which renderers and range
queries may read from other threads (reading the ``snapshot()`` reference is atomic; the
snapshot itself never changes).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pymunk

from components.motors.pwm import wheel_speed_rad_s
from components.sim.world.air import RadioAir
from components.sim.world.config import (
    BallConfig,
    Color,
    Distractor,
    Lighting,
    WorldConfig,
    WorldPose,
    box_corners,
    require_finite,
)
from components.sim.world.snapshot import BallState, DistractorState, RobotState, WorldSnapshot

__all__ = ["PUSH_LABEL", "ROBOT_COLOR", "RobotView", "StepHook", "World",
           "wrap_angle"]

ROBOT_COLOR: Color = (70, 72, 86)
"""The Mini-WHEGS's dark shell, as other robots' cameras see it."""

PUSH_LABEL = "push"
"""What :meth:`World.contacts` calls a hand's push (:meth:`World.shift_robot`)."""


def wrap_angle(angle_rad: float) -> float:
    """``angle_rad`` wrapped into ``[-π, π)``."""
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi


# --------------------------------------------------------------------------------------------
# World
# --------------------------------------------------------------------------------------------


@dataclass(slots=True)
class _RobotBody:
    """One Mini-WHEGS's body and drive state."""

    body: pymunk.Body
    pulses: tuple[float, float]
    wheel_speed: list[float]
    wheel_angle: list[float]
    touching: set[str] = field(default_factory=set)
    """What touched the robot (or pushed it by hand) during the step under way."""
    last_contact_ns: dict[str, int] = field(default_factory=dict)
    """Per thing that touched it (:meth:`World.contacts`), the end of the last step it did."""


@dataclass(slots=True)
class _FloorBody:
    """A dynamic body that rolls or slides on the floor (the ball, movable distractors)."""

    body: pymunk.Body
    damping_per_s: float
    """Viscous loss: deceleration = damping · v."""
    resistance: float
    """Coulomb loss: deceleration = resistance · g (rolling resistance or sliding friction)."""


StepHook = Callable[["World", float], None]
"""Called at the start of every ``World.step`` with the world and the step's dt."""


def _new_space() -> pymunk.Space:
    space = pymunk.Space()
    space.gravity = (0.0, 0.0)
    space.damping = 1.0
    space.collision_slop = 0.0005
    space.iterations = 20
    return space


class World:
    """The simulated Mini-WHEGS world.

    Step it from one thread. ``snapshot()`` and ``set_motor_pulses()`` may be called from any
    thread; the ball/robot placement helpers take the world's lock, so they are safe too.
    """

    index = 0
    """The robot :meth:`snapshot` and :meth:`set_motor_pulses` are about by default (a
    :class:`RobotView` is another robot's)."""

    def __init__(self, config: WorldConfig | None = None) -> None:
        self._config = cfg = config if config is not None else WorldConfig()
        self._lock = threading.RLock()
        self._rng = np.random.default_rng(cfg.seed)
        self._time_ns = 0  # whole nanoseconds: no drift however long the run
        self._step_count = 0
        self._hooks: list[StepHook] = []
        self._floor_bodies: list[_FloorBody] = []
        self._lighting = cfg.lighting

        self._space = _new_space()
        self._labels: dict[pymunk.Shape, str] = {}
        """What each shape is, for :meth:`contacts`: ``arena``, ``walls[i]``,
        ``obstacles[i]``, ``distractors[i]``, ``ball``, ``robot i``."""
        # The order things are added to the space is part of a seed's run: robots, ball,
        # walls, obstacles, distractors.
        self._robots = [self._add_robot(pose, index=i)
                        for i, pose in enumerate((cfg.robot_start, *cfg.more_robots))]
        self._robot = self._robots[0].body
        self.air = RadioAir(len(self._robots))
        """What the robots' ``radio.air`` backends send each other."""
        self._set_wheel_contacts(cfg)
        self._ball: _FloorBody | None = None
        if cfg.ball is not None:
            self._ball = self._add_ball(cfg.ball)
        self._walls = cfg.all_walls()
        self._add_static_geometry(cfg)
        self._distractor_bodies: list[pymunk.Body | None] = [
            self._add_distractor(index, d) for index, d in enumerate(cfg.distractors)]

        self._snapshots: dict[int, WorldSnapshot] = {}
        """Per robot, built on demand by :meth:`snapshot_for` (dropped when the world
        changes)."""

    def _set_wheel_contacts(self, cfg: WorldConfig) -> None:
        """The wheel-leg contacts and the friction they can carry (:meth:`_wheel_forces`)."""
        rc = cfg.robot
        # Wheel contacts (x, y, side, friction caps along and across) in the body frame;
        # side 0 = left (+y), 1 = right. A caster carries weight and no force: not listed.
        self._contacts = tuple(
            (x, y, side, rc.mu_longitudinal * load, rc.mu_lateral * load)
            for x, y, side, load in rc.wheel_contacts(rc.geometry.mass_kg * cfg.gravity_m_s2))
        self._inv_slip_long = 1.0 / rc.longitudinal_slip_m_s
        self._inv_slip_lat = 1.0 / rc.lateral_slip_m_s
        self._motors = (rc.left_motor, rc.right_motor)
        self._alpha: dict[float, float] = {}
        """The wheels' first-order lag factor per substep length (one or two lengths)."""

    def _add_ball(self, b: BallConfig) -> _FloorBody:
        ball = self._add_round_body(
            b.x_m, b.y_m, b.radius_m, b.mass_kg, elasticity=b.elasticity,
            damping_per_s=b.linear_damping_per_s, resistance=b.rolling_resistance,
        )
        self._labels.update(dict.fromkeys(ball.body.shapes, "ball"))
        return ball

    def _add_static_geometry(self, cfg: WorldConfig) -> None:
        """The arena's and the scenario's walls (``self._walls``), then the obstacle boxes."""
        static = self._space.static_body
        arena_walls = len(cfg.arena.walls()) if cfg.arena is not None else 0
        for i, wall in enumerate(self._walls):
            seg = pymunk.Segment(static, (wall.x1_m, wall.y1_m), (wall.x2_m, wall.y2_m), 0.0)
            self._add_static_shape(seg, "arena" if i < arena_walls else f"walls[{i - arena_walls}]")
        for i, box in enumerate(cfg.boxes):
            self._add_static_shape(pymunk.Poly(static, box.corners()), f"obstacles[{i}]")

    def _add_static_shape(self, shape: pymunk.Shape, label: str) -> None:
        shape.friction = 0.5
        shape.elasticity = 0.3
        self._space.add(shape)
        self._labels[shape] = label

    def _add_distractor(self, index: int, d: Distractor) -> pymunk.Body | None:
        """A distractor: a floor body when movable (its body returned), else a static shape."""
        label = f"distractors[{index}]"
        if d.movable and d.kind == "box":
            size = (d.length_m, d.width_m)
            mbody = pymunk.Body(d.mass_kg, pymunk.moment_for_box(d.mass_kg, size))
            mbody.position = (d.x_m, d.y_m)
            mbody.angle = d.yaw_rad
            mshape = pymunk.Poly.create_box(mbody, size)
            mshape.friction = 0.5
            mshape.elasticity = 0.3
            self._space.add(mbody, mshape)
            self._labels[mshape] = label
            # A box slides rather than rolls: strong Coulomb friction.
            self._floor_bodies.append(_FloorBody(mbody, 2.0, 0.4))
            return mbody
        if d.movable:
            fb = self._add_round_body(
                d.x_m, d.y_m, d.radius_m, d.mass_kg, elasticity=0.5,
                damping_per_s=0.5, resistance=0.02 if d.kind == "sphere" else 0.4,
            )
            self._labels.update(dict.fromkeys(fb.body.shapes, label))
            return fb.body
        static = self._space.static_body
        if d.kind == "box":
            corners = box_corners(d.x_m, d.y_m, d.yaw_rad, d.length_m, d.width_m)
            dshape: pymunk.Shape = pymunk.Poly(static, corners)
        else:
            dshape = pymunk.Circle(static, d.radius_m, offset=(d.x_m, d.y_m))
        self._add_static_shape(dshape, label)
        return None

    def _add_robot(self, pose: WorldPose, *, index: int) -> _RobotBody:
        rc = self._config.robot
        geo = rc.geometry
        moment = pymunk.moment_for_box(geo.mass_kg, (geo.length_m, geo.width_m))
        body = pymunk.Body(geo.mass_kg, moment)
        body.position = (pose.x_m, pose.y_m)
        body.angle = pose.heading_rad
        shell = pymunk.Poly.create_box(body, (geo.length_m, geo.width_m), radius=0.001)
        shell.friction = rc.body_friction
        shell.elasticity = 0.1
        self._space.add(body, shell)
        self._labels[shell] = f"robot {index}"
        return _RobotBody(body=body, pulses=(rc.left_motor.zero_ms, rc.right_motor.zero_ms),
                          wheel_speed=[0.0, 0.0], wheel_angle=[0.0, 0.0])

    def _add_round_body(
        self, x: float, y: float, radius: float, mass: float, *, elasticity: float,
        damping_per_s: float, resistance: float,
    ) -> _FloorBody:
        body = pymunk.Body(mass, pymunk.moment_for_circle(mass, 0.0, radius))
        body.position = (x, y)
        shape = pymunk.Circle(body, radius)
        shape.friction = 0.3
        shape.elasticity = elasticity
        self._space.add(body, shape)
        fb = _FloorBody(body, damping_per_s, resistance)
        self._floor_bodies.append(fb)
        return fb

    # -- properties ---------------------------------------------------------------------------

    @property
    def config(self) -> WorldConfig:
        return self._config

    @property
    def time_s(self) -> float:
        """Simulated time since the world was built, kept in whole nanoseconds: after
        720 000 steps of 5 ms it is exactly 3600.0 (a float sum would be off by 55 ns, and
        a clock held at exactly the run's end would never be reached)."""
        return self._time_ns / 1e9

    @property
    def rng(self) -> np.random.Generator:
        """The world's own generator (seeded from ``config.seed``), e.g. for scenario scripts."""
        return self._rng

    def make_rng(self, stream: int) -> np.random.Generator:
        """An independent generator for ``stream`` derived from ``config.seed``.

        Backends use fixed stream numbers so a run is reproducible from the one seed.
        """
        return np.random.default_rng([self._config.seed, stream])

    @property
    def motor_pulses(self) -> tuple[float, float]:
        """Robot 0's last pulses set, ``(left_ms, right_ms)``."""
        return self._robots[0].pulses

    @property
    def robot_count(self) -> int:
        """Robots in this world (1 + ``config.more_robots``)."""
        return len(self._robots)

    def robot(self, index: int) -> RobotView:
        """What the device backends use of a world, for robot ``index``."""
        if not 0 <= index < len(self._robots):
            raise IndexError(f"robot {index}: this world has robots 0…{len(self._robots) - 1}")
        return RobotView(self, index)

    # -- inputs -------------------------------------------------------------------------------

    def set_motor_pulses(self, left_ms: float, right_ms: float, *, robot: int = 0) -> None:
        """Set the PWM high time of each motor (ms) of ``robot``; takes effect at the next
        step."""
        require_finite(left_ms=left_ms, right_ms=right_ms)
        self._robots[robot].pulses = (float(left_ms), float(right_ms))

    def set_ball_velocity(self, vx_m_s: float, vy_m_s: float) -> None:
        """Give the ball a velocity (it then rolls and slows down on its own)."""
        require_finite(vx_m_s=vx_m_s, vy_m_s=vy_m_s)
        ball = self._require_ball()
        with self._lock:
            ball.body.velocity = (vx_m_s, vy_m_s)
            self._snapshots = {}

    def place_ball(self, x_m: float, y_m: float) -> None:
        """Teleport the ball to (x, y) and stop it."""
        require_finite(x_m=x_m, y_m=y_m)
        ball = self._require_ball()
        with self._lock:
            ball.body.position = (x_m, y_m)
            ball.body.velocity = (0.0, 0.0)
            ball.body.angular_velocity = 0.0
            self._space.reindex_shapes_for_body(ball.body)
            self._snapshots = {}

    def place_robot(self, pose: WorldPose, *, robot: int = 0) -> None:
        """Teleport ``robot`` to ``pose`` and stop it (wheel angles are kept)."""
        with self._lock:
            body = self._robots[robot].body
            body.position = (pose.x_m, pose.y_m)
            body.angle = pose.heading_rad
            body.velocity = (0.0, 0.0)
            body.angular_velocity = 0.0
            self._space.reindex_shapes_for_body(body)
            self._snapshots = {}

    def place_distractor(self, index: int, x_m: float, y_m: float) -> None:
        """Teleport movable distractor ``index`` (order of ``config.distractors``) to (x, y)
        and stop it. Raises ``ValueError`` for a static one (its shape is fixed)."""
        require_finite(x_m=x_m, y_m=y_m)
        body = self._distractor_bodies[index]
        if body is None:
            raise ValueError(f"distractor {index} is static: only a movable one can be moved")
        with self._lock:
            body.position = (x_m, y_m)
            body.velocity = (0.0, 0.0)
            body.angular_velocity = 0.0
            self._space.reindex_shapes_for_body(body)
            self._snapshots = {}

    def shift_robot(self, dx_m: float, dy_m: float, d_heading_rad: float = 0.0) -> None:
        """Move the robot by (dx, dy) and turn it by ``d_heading_rad`` as a hand pushing it
        would: its velocities and wheels are left alone (the encoders see nothing)."""
        require_finite(dx_m=dx_m, dy_m=dy_m, d_heading_rad=d_heading_rad)
        with self._lock:
            x, y = self._robot.position
            self._robot.position = (x + dx_m, y + dy_m)
            self._robot.angle = self._robot.angle + d_heading_rad
            self._space.reindex_shapes_for_body(self._robot)
            self._robots[0].touching.add(PUSH_LABEL)
            self._snapshots = {}

    def contacts(self, *, robot: int = 0) -> dict[str, float]:
        """What has touched robot ``robot`` so far — ``arena`` (its walls), ``walls[i]``,
        ``obstacles[i]``, ``distractors[i]``, ``ball``, ``robot i``, or ``push`` (a hand,
        :meth:`shift_robot`) — each with the simulated time at the end of the last step it
        did. A body pressed against something or shoved moves without its wheels saying so:
        the encoders' odometry cannot follow it (the runner's summary reports these periods).
        """
        with self._lock:
            return {label: ns / 1e9
                    for label, ns in self._robots[robot].last_contact_ns.items()}

    def set_lighting(self, lighting: Lighting) -> None:
        """Change the scene lighting (seen by the camera from the next snapshot on)."""
        with self._lock:
            self._lighting = lighting
            self._snapshots = {}

    def add_step_hook(self, hook: StepHook) -> Callable[[], None]:
        """Run ``hook(world, dt_s)`` at the start of every step (scripted motion, scenarios).

        Returns a function that removes the hook again.
        """
        with self._lock:
            self._hooks.append(hook)

        def remove() -> None:
            with self._lock:
                if hook in self._hooks:
                    self._hooks.remove(hook)

        return remove

    def _require_ball(self) -> _FloorBody:
        if self._ball is None:
            raise RuntimeError("this world has no ball (WorldConfig.ball is None)")
        return self._ball

    # -- stepping -----------------------------------------------------------------------------

    def step(self, dt_s: float) -> WorldSnapshot:
        """Advance by ``dt_s`` in equal substeps no longer than ``config.substep_s``.

        Simulated time advances by ``dt_s`` rounded to whole nanoseconds. Returns the new
        snapshot (:meth:`advance` does the same without building it).
        """
        self.advance(dt_s)
        return self.snapshot()

    def advance(self, dt_s: float) -> None:
        """:meth:`step` without building the snapshot: the next :meth:`snapshot` call builds
        it (the simulator steps many times between two readers)."""
        if not (math.isfinite(dt_s) and dt_s >= 0.0):
            raise ValueError(f"dt_s must be a finite number >= 0, got {dt_s!r}")
        with self._lock:
            for hook in tuple(self._hooks):
                hook(self, dt_s)
            if dt_s > 0.0:
                n = max(1, math.ceil(dt_s / self._config.substep_s - 1e-9))
                h = dt_s / n
                # The pulses hold for the whole step (set_motor_pulses: "at the next step").
                targets = [(wheel_speed_rad_s(self._motors[0], r.pulses[0]),
                            wheel_speed_rad_s(self._motors[1], r.pulses[1]))
                           for r in self._robots]
                for _ in range(n):
                    self._substep(h, targets)
                self._time_ns += round(dt_s * 1e9)
            for robot in self._robots:
                if robot.touching:
                    for label in robot.touching:
                        robot.last_contact_ns[label] = self._time_ns
                    robot.touching.clear()
            self._step_count += 1
            self._snapshots = {}

    def _drive(self, robot: _RobotBody, h: float, targets: tuple[float, float],
               alpha: float) -> None:
        """One robot's wheels and ground contact forces over a substep of ``h``."""
        radius = self._config.robot.geometry.wheel_radius_m
        surface = [0.0, 0.0]
        wheel_speed, wheel_angle = robot.wheel_speed, robot.wheel_angle
        for side in (0, 1):
            target = targets[side]
            old = wheel_speed[side]
            new = old + (target - old) * alpha
            wheel_speed[side] = new
            wheel_angle[side] += 0.5 * (old + new) * h
            surface[side] = new * radius

        # Ground contact forces on the robot, computed in the body frame (module docstring).
        body = robot.body
        heading = body.angle
        c, s = math.cos(heading), math.sin(heading)
        vx, vy = body.velocity
        omega = body.angular_velocity
        vxb = c * vx + s * vy
        vyb = -s * vx + c * vy
        inv_long, inv_lat = self._inv_slip_long, self._inv_slip_lat
        fx_sum = fy_sum = torque = 0.0
        kx_sum = ky_sum = kw_sum = 0.0  # force (torque) per unit slip, for the implicit step
        for ax, ay, side, cap_long, cap_lat in self._contacts:
            # Slip in units of the slip that mobilises full friction in each direction.
            sx = (vxb - omega * ay - surface[side]) * inv_long
            sy = (vyb + omega * ax) * inv_lat
            slip = math.hypot(sx, sy)
            scale = 1.0 / slip if slip > 1.0 else 1.0  # on the friction ellipse, or linear
            kx = cap_long * scale
            ky = cap_lat * scale
            fx = -kx * sx
            fy = -ky * sy
            fx_sum += fx
            fy_sum += fy
            torque += ax * fy - ay * fx
            kx *= inv_long
            ky *= inv_lat
            kx_sum += kx
            ky_sum += ky
            kw_sum += kx * ay * ay + ky * ax * ax
        # Semi-implicit: scale each axis by 1 / (1 + h·k/m), as a backward-Euler step of the
        # linearised contact would, so the stiff lateral grip cannot overshoot.
        mass, moment = body.mass, body.moment
        fx_sum /= 1.0 + h * kx_sum / mass
        fy_sum /= 1.0 + h * ky_sum / mass
        torque /= 1.0 + h * kw_sum / moment
        body.force = (c * fx_sum - s * fy_sum, s * fx_sum + c * fy_sum)
        body.torque = torque

    def _substep(self, h: float, targets: list[tuple[float, float]]) -> None:
        cfg = self._config
        rc = cfg.robot
        alpha = self._alpha.get(h)
        if alpha is None:
            alpha = self._alpha[h] = 1.0 - math.exp(-h / rc.motor_time_constant_s)
        for robot, target in zip(self._robots, targets, strict=True):
            self._drive(robot, h, target, alpha)

        # Rolling / sliding losses of free bodies.
        g = cfg.gravity_m_s2
        spin_decay = math.exp(-5.0 * h)
        for fb in self._floor_bodies:
            b = fb.body
            bvx, bvy = b.velocity
            speed = math.hypot(bvx, bvy)
            coulomb = fb.resistance * g
            if speed <= coulomb * h:
                if speed > 0.0:
                    b.velocity = (0.0, 0.0)
            else:
                decel = fb.damping_per_s * speed + coulomb
                scale = -b.mass * decel / speed
                b.force = (bvx * scale, bvy * scale)
            spin = b.angular_velocity
            if spin != 0.0:
                b.angular_velocity = spin * spin_decay

        self._space.step(h)
        # What each robot touches (pymunk lists only the arbiters with contact points): one
        # call per robot and substep, cheap when nothing touches.
        for robot in self._robots:
            robot.body.each_arbiter(self._note_contact, robot)

    def _note_contact(self, arbiter: pymunk.Arbiter, robot: _RobotBody) -> None:
        a, b = arbiter.shapes
        other = b if a.body is robot.body else a
        robot.touching.add(self._labels.get(other, "something"))

    # -- snapshot -----------------------------------------------------------------------------

    def snapshot(self) -> WorldSnapshot:
        """Robot 0's latest immutable snapshot (replaced after every step; built on first
        demand)."""
        return self.snapshot_for(0)

    def snapshot_for(self, robot: int) -> WorldSnapshot:
        """The world as robot ``robot`` senses it: itself as ``robot``, the other robots
        among the ``distractors`` (dark boxes, after the configured ones), so its camera and
        IR see them."""
        snap = self._snapshots.get(robot)
        if snap is not None:
            return snap
        with self._lock:
            snap = self._snapshots.get(robot)
            if snap is None:
                snap = self._snapshots[robot] = self._make_snapshot(robot)
            return snap

    def _make_snapshot(self, index: int) -> WorldSnapshot:
        cfg = self._config
        me = self._robots[index]
        body = me.body
        geo = cfg.robot.geometry
        x, y = body.position
        vx, vy = body.velocity
        robot = RobotState(
            x_m=float(x), y_m=float(y),
            heading_rad=wrap_angle(body.angle), heading_unwrapped_rad=float(body.angle),
            vx_m_s=float(vx), vy_m_s=float(vy), yaw_rate_rad_s=float(body.angular_velocity),
            left_wheel_angle_rad=me.wheel_angle[0],
            right_wheel_angle_rad=me.wheel_angle[1],
            left_wheel_speed_rad_s=me.wheel_speed[0],
            right_wheel_speed_rad_s=me.wheel_speed[1],
            left_pulse_ms=me.pulses[0], right_pulse_ms=me.pulses[1],
            length_m=geo.length_m, width_m=geo.width_m,
        )
        ball_state = None
        if self._ball is not None and cfg.ball is not None:
            bx, by = self._ball.body.position
            bvx, bvy = self._ball.body.velocity
            ball_state = BallState(
                x_m=float(bx), y_m=float(by), vx_m_s=float(bvx), vy_m_s=float(bvy),
                radius_m=cfg.ball.radius_m, color=cfg.ball.color,
            )
        distractors = []
        for d, dbody in zip(cfg.distractors, self._distractor_bodies, strict=True):
            if dbody is None:
                dx, dy, dyaw = d.x_m, d.y_m, d.yaw_rad
            else:
                dx, dy = (float(v) for v in dbody.position)
                dyaw = float(dbody.angle)
            distractors.append(
                DistractorState(
                    kind=d.kind, x_m=dx, y_m=dy, yaw_rad=dyaw, radius_m=d.radius_m,
                    length_m=d.length_m, width_m=d.width_m, height_m=d.effective_height_m,
                    color=d.color,
                )
            )
        for other in self._robots:
            if other is not me:
                ox, oy = other.body.position
                distractors.append(DistractorState(
                    kind="box", x_m=float(ox), y_m=float(oy), yaw_rad=float(other.body.angle),
                    radius_m=geo.width_m / 2, length_m=geo.length_m, width_m=geo.width_m,
                    height_m=cfg.robot.height_m, color=ROBOT_COLOR))
        return WorldSnapshot(
            time_s=self._time_ns / 1e9,
            step_count=self._step_count,
            robot=robot,
            ball=ball_state,
            walls=self._walls,
            boxes=tuple(cfg.boxes),
            distractors=tuple(distractors),
            lighting=self._lighting,
        )


class RobotView:
    """One robot of a :class:`World`, as the device backends use a world (``snapshot()``,
    ``set_motor_pulses()``, ``config``, ``make_rng()``): each robot of a fleet gets its own
    devices on the one world. Its random streams differ from the other robots'."""

    def __init__(self, world: World, index: int) -> None:
        self.world = world
        self.index = index
        self.air = world.air

    @property
    def config(self) -> WorldConfig:
        return self.world.config

    @property
    def time_s(self) -> float:
        return self.world.time_s

    def snapshot(self) -> WorldSnapshot:
        return self.world.snapshot_for(self.index)

    def set_motor_pulses(self, left_ms: float, right_ms: float) -> None:
        self.world.set_motor_pulses(left_ms, right_ms, robot=self.index)

    @property
    def motor_pulses(self) -> tuple[float, float]:
        return self.world._robots[self.index].pulses

    def make_rng(self, stream: int) -> np.random.Generator:
        if self.index == 0:
            return self.world.make_rng(stream)
        return np.random.default_rng([self.world.config.seed, stream, self.index])
