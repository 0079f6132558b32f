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


class RangeReadError(OSError):
    """A real sensor could not be read this time (an I²C bus error, a conversion that never
    finished): the range component counts it and publishes nothing for that period."""


class RangeBackend(Protocol):
    """Returns the distance from the sensor along its beam to the first surface.

    ``None`` when nothing lies within ``max_range_m``. A simulated backend reports the true
    geometry and the HAL adds the device's 5–10 % error; a real sensor's backend sets
    ``measured = True`` (its distance is already a measurement, with the sensor's own error:
    the HAL only applies the model's limits) and ``blocking = True`` when a read waits on a bus
    (the HAL then reads it in a worker thread, never on the event loop). A failed read raises
    :class:`RangeReadError`.
    """

    def distance_m(self, mount: MountPose, *, max_range_m: float) -> float | None:
        ...
