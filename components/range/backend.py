"""What an IR range finder measures through: the true distance along its beam."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from ubf_async.assembly.backend import Backend
from ubf_async.errors import DeviceError

__all__ = ["MountPose", "RangeBackend", "RangeReadError"]


@dataclass(frozen=True, slots=True, kw_only=True)
class MountPose:
    """Where a sensor sits on the robot, in the robot frame (REP-103: x forward, y left)."""

    x_m: float = 0.05
    y_m: float = 0.0
    yaw_rad: float = 0.0


class RangeReadError(DeviceError):
    """A real sensor could not be read this time (an I²C bus error, a conversion that never
    finished): the range component counts it and publishes nothing for that period."""


class RangeBackend(Backend):
    """Returns the distance from the sensor along its beam to the first surface.

    ``None`` when nothing lies within ``max_range_m``. A simulated backend reports the true
    geometry and the HAL adds the device's 5–10 % error. A failed read raises
    :class:`RangeReadError`.
    """

    measured: ClassVar[bool] = False
    """True for a real sensor's backend: its distance is already a measurement, with the
    sensor's own error, and the HAL only applies the model's limits. False (the default): the
    true geometry, to which the HAL adds the model's error."""
    blocking: ClassVar[bool] = False
    """True when a read waits on a bus: the HAL then reads in a worker thread, never on the
    event loop. False (the default): a read returns at once."""
    model: str | None = None
    """The thesis model (``ir-10-80``…) whose curve the backend reads, which the device's
    model must then be; None (the default): any."""

    def distance_m(self, mount: MountPose, *, max_range_m: float) -> float | None:
        raise NotImplementedError
