"""What a running :class:`~components.sim.world.physics.World` shows its readers: immutable
snapshots.

:class:`WorldSnapshot` is the world as one robot senses it after a step — the robot's own state
(:class:`RobotState`), the ball (:class:`BallState`), the walls, boxes and lighting of its
:class:`~components.sim.world.config.WorldConfig`, and the distractors where they are now
(:class:`DistractorState`; the other robots of a fleet among them). Plain frozen values, safe to
share between threads and to rebuild in other processes
(:mod:`components.sim.world.snapshot_data`): the camera renderer, the range finders, recordings
and live views read them without the physics.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from components.sim.world.config import BoxObstacle, Color, DistractorKind, Lighting, Wall

__all__ = ["BallState", "DistractorState", "RobotState", "WorldSnapshot"]


@dataclass(frozen=True, slots=True, kw_only=True)
class RobotState:
    x_m: float
    y_m: float
    heading_rad: float
    """Wrapped into ``[-π, π)``."""
    heading_unwrapped_rad: float
    """Continuous heading (counts full turns)."""
    vx_m_s: float
    """World-frame velocity."""
    vy_m_s: float
    yaw_rate_rad_s: float
    left_wheel_angle_rad: float
    right_wheel_angle_rad: float
    left_wheel_speed_rad_s: float
    right_wheel_speed_rad_s: float
    left_pulse_ms: float
    right_pulse_ms: float
    length_m: float
    width_m: float

    @property
    def forward_speed_m_s(self) -> float:
        """Velocity along the robot's heading."""
        return self.vx_m_s * math.cos(self.heading_rad) + self.vy_m_s * math.sin(self.heading_rad)


@dataclass(frozen=True, slots=True, kw_only=True)
class BallState:
    x_m: float
    y_m: float
    vx_m_s: float
    vy_m_s: float
    radius_m: float
    color: Color


@dataclass(frozen=True, slots=True, kw_only=True)
class DistractorState:
    kind: DistractorKind
    x_m: float
    y_m: float
    yaw_rad: float
    radius_m: float
    length_m: float
    width_m: float
    height_m: float
    color: Color


@dataclass(frozen=True, slots=True, kw_only=True)
class WorldSnapshot:
    """Immutable picture of the world after a step; safe to share between threads."""

    time_s: float
    step_count: int
    robot: RobotState
    ball: BallState | None
    walls: tuple[Wall, ...]
    boxes: tuple[BoxObstacle, ...]
    distractors: tuple[DistractorState, ...]
    lighting: Lighting
