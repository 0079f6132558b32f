"""What an IR range finder measures through: the true distance along its beam."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol


@dataclass(frozen=True, slots=True, kw_only=True)
class MountPose:
    """Where a sensor sits on the robot, in the robot frame (REP-103: x forward, y left)."""

    x_m: float = 0.05
    y_m: float = 0.0
    yaw_rad: float = 0.0


class RangeBackend(Protocol):
    """Returns the true distance from the sensor along its beam to the first surface.

    ``None`` when nothing lies within ``max_range_m``. The HAL adds the device's error and
    applies its minimum range; the backend reports geometry only.
    """

    def distance_m(self, mount: MountPose, *, max_range_m: float) -> float | None:
        ...
