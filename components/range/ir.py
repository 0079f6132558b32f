"""The thesis's three I²C infrared range finders as data, and their reading model (pure).

The robot could carry Sharp GP2Y0A-family sensors of three ranges (DESIGN.md §3): 4–30 cm,
10–80 cm and 20–150 cm, read in millimetres, each deviating 5–10 % from the true distance.
The backend supplies the true distance along the beam; :func:`read_ir` turns it into what the
device reports. Out-of-range readings are a status, not a number: a Sharp sensor's output is
ambiguous below its minimum range and meaningless beyond its maximum.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

__all__ = ["DEFAULT_ERROR_FRACTION", "GP2Y0A02", "GP2Y0A21", "GP2Y0A41", "IR_MODELS", "IrModel",
           "IrReading", "IrStatus", "limit_ir", "read_ir"]

IrStatus = Literal["ok", "too_close", "too_far"]


@dataclass(frozen=True, slots=True, kw_only=True)
class IrModel:
    """One range-finder model: a name and the distances it can measure."""

    name: str
    min_range_m: float
    max_range_m: float

    def __post_init__(self) -> None:
        if not self.name:
            raise ValueError("IrModel.name must not be empty")
        if not (math.isfinite(self.min_range_m) and math.isfinite(self.max_range_m)):
            raise ValueError(
                f"IrModel ranges must be finite, got {self.min_range_m}…{self.max_range_m}"
            )
        if not 0.0 < self.min_range_m < self.max_range_m:
            raise ValueError(
                "IrModel needs 0 < min_range_m < max_range_m, got "
                f"{self.min_range_m}…{self.max_range_m}"
            )


GP2Y0A41 = IrModel(name="ir-4-30", min_range_m=0.04, max_range_m=0.30)
GP2Y0A21 = IrModel(name="ir-10-80", min_range_m=0.10, max_range_m=0.80)
GP2Y0A02 = IrModel(name="ir-20-150", min_range_m=0.20, max_range_m=1.50)
IR_MODELS: dict[str, IrModel] = {m.name: m for m in (GP2Y0A41, GP2Y0A21, GP2Y0A02)}
"""The three models by name (``"ir-4-30"``, ``"ir-10-80"``, ``"ir-20-150"``)."""

DEFAULT_ERROR_FRACTION = (0.05, 0.10)
"""The thesis measured readings 5–10 % off the true distance."""


@dataclass(frozen=True, slots=True, kw_only=True)
class IrReading:
    """What the device reports: a distance in whole millimetres, or why there is none."""

    range_mm: int | None
    status: IrStatus


def read_ir(
    model: IrModel,
    true_distance_m: float | None,
    *,
    rng: np.random.Generator,
    error_fraction: tuple[float, float] = DEFAULT_ERROR_FRACTION,
) -> IrReading:
    """Simulate one reading of ``model`` for a surface at ``true_distance_m``.

    ``None`` (nothing along the beam) or a distance beyond the maximum reads ``too_far``; below
    the minimum ``too_close``; both without a number. Otherwise the true distance is multiplied
    by ``1 ± e`` with ``e`` uniform in ``error_fraction`` and a random sign, clipped to the
    model's range and rounded to whole millimetres. The bounds are inclusive.
    """
    lo, hi = error_fraction
    if not (math.isfinite(lo) and math.isfinite(hi) and 0.0 <= lo <= hi < 1.0):
        raise ValueError(f"error_fraction must satisfy 0 <= lo <= hi < 1, got {error_fraction}")
    if true_distance_m is None:
        return IrReading(range_mm=None, status="too_far")
    if math.isnan(true_distance_m) or true_distance_m < 0.0:
        raise ValueError(f"true_distance_m must be >= 0 or None, got {true_distance_m!r}")
    if true_distance_m > model.max_range_m:
        return IrReading(range_mm=None, status="too_far")
    if true_distance_m < model.min_range_m:
        return IrReading(range_mm=None, status="too_close")
    error = rng.uniform(lo, hi) * (1.0 if rng.random() < 0.5 else -1.0)
    measured_m = min(max(true_distance_m * (1.0 + error), model.min_range_m), model.max_range_m)
    return IrReading(range_mm=round(measured_m * 1000.0), status="ok")


def limit_ir(model: IrModel, measured_distance_m: float | None) -> IrReading:
    """What the device reports for a real sensor's own measurement: the model's limits
    applied (out of range is a status, not a number), no simulated error added."""
    if measured_distance_m is None or not measured_distance_m <= model.max_range_m:
        return IrReading(range_mm=None, status="too_far")  # None, beyond the range, or NaN
    if measured_distance_m < model.min_range_m:
        return IrReading(range_mm=None, status="too_close")
    return IrReading(range_mm=round(measured_distance_m * 1000.0), status="ok")
