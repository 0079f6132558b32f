"""Differential-drive dead reckoning from wheel rotations (pure logic).

The Mini-WHEGS skid-steers: the left and right wheel-leg pairs each have one motor and one
encoder. Treating each side as a wheel of ``wheel_radius_m`` at ``track_width_m`` apart, a step
in which the left wheel turns ``dθl`` and the right ``dθr`` moves the robot along an arc:

* distance of the robot's centre ``ds = r·(dθl + dθr)/2``
* heading change ``dψ = r·(dθr − dθl)/track`` (REP-103: positive = counter-clockwise = left)

``track`` is the **effective** track: a skid-steer robot's wheel-legs slide sideways in a
turn, so the body yaws only a fraction of what the physical track (6 cm) implies — about
1/7 for the Mini-WHEGS, whose heading would otherwise read ≈7× the true yaw. Real skid-steer
drivers calibrate it (ROS's ``wheel_separation_multiplier``); ``effective_track_m`` defaults to
:data:`EFFECTIVE_TRACK_M`, measured on the simulated robot with
``python -m components.encoders.calibrate`` (which also fits it for a real one).

The step is integrated **exactly** for that arc (constant curvature during the step): the
robot moves along the chord ``2·(ds/dψ)·sin(dψ/2)`` in the direction ``ψ + dψ/2``, which tends
to ``ds`` along ``ψ`` for a straight step. Splitting a constant arc into many small steps
therefore gives the same pose as one big step; the only error left is the real wheels'
(slip, which skid steering has plenty of).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from components.miniwhegs import MINI_WHEGS, MiniWhegsGeometry

__all__ = ["EFFECTIVE_TRACK_M", "OdometryPose", "WheelOdometry", "wrap_angle"]


def wrap_angle(angle_rad: float) -> float:
    """``angle_rad`` wrapped to ``(−π, π]``."""
    wrapped = math.remainder(angle_rad, 2.0 * math.pi)
    return math.pi if wrapped <= -math.pi else wrapped


@dataclass(frozen=True, slots=True, kw_only=True)
class OdometryPose:
    """Planar pose in the odometry frame (REP-103: x forward at start, y left)."""

    x_m: float = 0.0
    y_m: float = 0.0
    heading_rad: float = 0.0
    """Counter-clockwise from the x axis, in ``(−π, π]``."""


EFFECTIVE_TRACK_M = 0.42
"""The Mini-WHEGS's effective track for odometry, fitted by ``python -m
components.encoders.calibrate`` on the simulated robot over the thesis's drive commands (the
physical track is 6 cm; the ground lets the body yaw ≈14 % of the kinematic rate)."""


def _sinc(x: float) -> float:
    """``sin(x)/x`` with the removable singularity at 0 handled."""
    if abs(x) < 1e-6:
        return 1.0 - x * x / 6.0
    return math.sin(x) / x


class WheelOdometry:
    """Accumulates a :class:`OdometryPose` from per-step wheel rotation increments."""

    def __init__(
        self,
        geometry: MiniWhegsGeometry = MINI_WHEGS,
        *,
        pose: OdometryPose | None = None,
        effective_track_m: float | None = None,
    ) -> None:
        """``effective_track_m``: the track the heading is integrated with (see the module
        docstring); ``None`` uses the geometry's physical ``track_width_m`` (a robot whose
        wheels do not slip sideways)."""
        if geometry.wheel_radius_m <= 0.0 or geometry.track_width_m <= 0.0:
            raise ValueError(
                "geometry needs a positive wheel_radius_m and track_width_m, got "
                f"{geometry.wheel_radius_m} and {geometry.track_width_m}"
            )
        track = geometry.track_width_m if effective_track_m is None else effective_track_m
        if not (math.isfinite(track) and track > 0.0):
            raise ValueError(f"effective_track_m must be a positive number, got {track!r}")
        self.geometry = geometry
        self.track_m = track
        self._pose = OdometryPose()
        self._heading_unwrapped_rad = 0.0
        self.reset(pose or OdometryPose())

    @property
    def pose(self) -> OdometryPose:
        return self._pose

    @property
    def heading_unwrapped_rad(self) -> float:
        """The heading without wrapping: the start pose's plus every change since, so full
        turns count (``pose.heading_rad`` is this wrapped). An error in the heading may grow
        past 180° in a long run; only the unwrapped heading shows it."""
        return self._heading_unwrapped_rad

    def reset(self, pose: OdometryPose | None = None) -> None:
        """Start again from ``pose`` (the origin by default)."""
        pose = pose or OdometryPose()
        for name in ("x_m", "y_m", "heading_rad"):
            if not math.isfinite(getattr(pose, name)):
                raise ValueError(f"pose.{name} must be finite, got {getattr(pose, name)!r}")
        self._pose = OdometryPose(x_m=pose.x_m, y_m=pose.y_m,
                                  heading_rad=wrap_angle(pose.heading_rad))
        self._heading_unwrapped_rad = pose.heading_rad

    def update(self, d_left_rad: float, d_right_rad: float) -> OdometryPose:
        """Advance by the wheel rotations since the previous update and return the new pose."""
        if not (math.isfinite(d_left_rad) and math.isfinite(d_right_rad)):
            raise ValueError(
                f"wheel increments must be finite, got left={d_left_rad!r} right={d_right_rad!r}"
            )
        r = self.geometry.wheel_radius_m
        ds = r * (d_left_rad + d_right_rad) / 2.0
        d_heading = r * (d_right_rad - d_left_rad) / self.track_m
        half = d_heading / 2.0
        chord = ds * _sinc(half)
        direction = self._pose.heading_rad + half
        self._pose = OdometryPose(
            x_m=self._pose.x_m + chord * math.cos(direction),
            y_m=self._pose.y_m + chord * math.sin(direction),
            heading_rad=wrap_angle(self._pose.heading_rad + d_heading),
        )
        self._heading_unwrapped_rad += d_heading
        return self._pose
