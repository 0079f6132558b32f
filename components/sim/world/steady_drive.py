"""The robot's steady motion for fixed pulses, measured in an empty world.

Run ``python -m components.sim.world.steady_drive`` to print the steady yaw rates and speeds of the
thesis's commands (:data:`THESIS_DRIVE_COMMANDS`) through the default HAL calibration, and the
yaw fraction κ the linearised contact model predicts; :mod:`components.sim.world.physics`
explains the contact model and tabulates the result for the defaults.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from components.motors.pwm import pulse_widths
from components.sim.world.config import RobotConfig, WorldConfig
from components.sim.world.physics import World

__all__ = ["THESIS_DRIVE_COMMANDS", "SteadyDrive", "drive_table", "format_drive_table",
           "steady_drive"]


@dataclass(frozen=True, slots=True, kw_only=True)
class SteadyDrive:
    """The robot's steady motion for fixed pulses, measured in an empty world."""

    left_ms: float
    right_ms: float
    yaw_rate_rad_s: float
    """Mean yaw rate over the measuring window (CCW positive)."""
    forward_speed_m_s: float
    """Mean speed along the heading over the window (path length / time for a circle)."""
    kinematic_yaw_rate_rad_s: float
    """``(v_R − v_L)/track`` from the wheel surface speeds: the yaw rate without slip."""
    kinematic_speed_m_s: float
    """``(v_L + v_R)/2`` from the wheel surface speeds."""

    @property
    def yaw_rate_deg_s(self) -> float:
        return math.degrees(self.yaw_rate_rad_s)

    @property
    def kinematic_yaw_rate_deg_s(self) -> float:
        return math.degrees(self.kinematic_yaw_rate_rad_s)

    @property
    def turn_radius_m(self) -> float:
        """Radius of the driven circle (``inf`` when not turning)."""
        if abs(self.yaw_rate_rad_s) < 1e-6:
            return math.inf
        return abs(self.forward_speed_m_s / self.yaw_rate_rad_s)


def steady_drive(
    left_ms: float,
    right_ms: float,
    *,
    robot: RobotConfig | None = None,
    settle_s: float = 2.0,
    window_s: float = 2.0,
    dt_s: float = 0.005,
) -> SteadyDrive:
    """Drive an empty world with fixed pulses, let it settle, and measure the mean motion."""
    world = World(WorldConfig(robot=robot if robot is not None else RobotConfig()))
    world.set_motor_pulses(left_ms, right_ms)
    for _ in range(round(settle_s / dt_s)):
        world.step(dt_s)
    start = world.snapshot().robot
    forward = 0.0
    steps = round(window_s / dt_s)
    for _ in range(steps):
        forward += world.step(dt_s).robot.forward_speed_m_s
    end = world.snapshot().robot
    rc = world.config.robot
    radius = rc.geometry.wheel_radius_m
    v_left = end.left_wheel_speed_rad_s * radius
    v_right = end.right_wheel_speed_rad_s * radius
    return SteadyDrive(
        left_ms=left_ms,
        right_ms=right_ms,
        yaw_rate_rad_s=(end.heading_unwrapped_rad - start.heading_unwrapped_rad) / window_s,
        forward_speed_m_s=forward / steps,
        kinematic_yaw_rate_rad_s=(v_right - v_left) / rc.geometry.track_width_m,
        kinematic_speed_m_s=0.5 * (v_left + v_right),
    )


THESIS_DRIVE_COMMANDS: tuple[tuple[float, float], ...] = (
    (40.0, 0.0), (40.0, 30.0), (40.0, 60.0), (10.0, 80.0), (0.0, 100.0),
)
"""speed/turn pairs of the thesis's behaviours: chase straight, chase ±30, chase ±60, search,
and a full in-place turn."""


def drive_table(
    commands: tuple[tuple[float, float], ...] = THESIS_DRIVE_COMMANDS,
    *,
    robot: RobotConfig | None = None,
) -> list[tuple[float, float, SteadyDrive]]:
    """``(speed, turn, SteadyDrive)`` for each command, through the default HAL calibration."""
    rows = []
    for speed, turn in commands:
        pulses = pulse_widths(speed, turn)
        rows.append(
            (speed, turn, steady_drive(pulses.left_ms, pulses.right_ms, robot=robot))
        )
    return rows


def _tidy(value: float, resolution: float) -> float:
    """``value``, or 0.0 when it would print as ±0 (no "-0.0" in tables)."""
    return 0.0 if abs(value) < resolution else value


def format_drive_table(rows: list[tuple[float, float, SteadyDrive]]) -> str:
    """A plain-text table of :func:`drive_table` rows."""
    lines = [
        "speed/turn   yaw °/s  kinematic °/s  fraction  forward m/s  kinematic m/s  radius m"
    ]
    for speed, turn, d in rows:
        kinematic = d.kinematic_yaw_rate_rad_s
        fraction = f"{d.yaw_rate_rad_s / kinematic:8.3f}" if abs(kinematic) > 1e-6 else "       -"
        yaw, kin_yaw = _tidy(d.yaw_rate_deg_s, 0.05), _tidy(d.kinematic_yaw_rate_deg_s, 0.05)
        lines.append(
            f"{speed:+4.0f}/{turn:+4.0f}  {yaw:+8.1f}  {kin_yaw:+13.1f}  {fraction}  "
            f"{_tidy(d.forward_speed_m_s, 5e-4):+11.3f}  "
            f"{_tidy(d.kinematic_speed_m_s, 5e-4):+13.3f}  {d.turn_radius_m:8.3f}"
        )
    return "\n".join(lines)


if __name__ == "__main__":
    print(f"yaw fraction κ (linearised): {RobotConfig().yaw_fraction:.3f}")
    print(format_drive_table(drive_table()))
