"""The IR range-finder component: one sensor of a thesis model at a mounting pose.

Every ``period_s`` (robot clock) it asks its backend for the distance along the beam. For a
simulated backend (the true distance) it applies the model's range limits and 5–10 % error
(:func:`components.range.ir.read_ir`); for a real sensor (``measured``) only the limits
(:func:`~components.range.ir.limit_ir`), reading a ``blocking`` one in a worker thread; a
failed read (:class:`~components.range.backend.RangeReadError`) is counted in
``read_errors`` and skips that sample. It publishes ``sensor/range/<name>`` (schema
``range``): ``range_mm`` and ``status`` — out of range is reported as
``too_close``/``too_far`` with ``range_mm`` nil, never as a number.
"""

from __future__ import annotations

import asyncio
import logging
import math
from typing import Annotated, Literal

import msgspec
import numpy as np

from components.range.backend import MountPose, RangeBackend, RangeReadError
from components.range.ir import GP2Y0A21, IR_MODELS, IrModel, limit_ir, read_ir
from ubf_async import throttle
from ubf_async.clocks.clock import every
from ubf_async.errors import ConfigurationError
from ubf_async.runtime.bus import Bus
from ubf_async.runtime.component import Component
from ubf_async.wire.topics import RANGE

__all__ = ["ModelName", "RangeComponent", "build_device"]

log = logging.getLogger(__name__)


class RangeComponent(Component):
    def __init__(
        self,
        *,
        bus: Bus,
        backend: RangeBackend,
        name: str = "front",
        model: IrModel = GP2Y0A21,
        mount: MountPose | None = None,
        period_s: float = 0.04,
        seed: int | None = None,
        **component_options: float,
    ) -> None:
        super().__init__(bus=bus, name=f"range-{name}", **component_options)
        if not period_s > 0:
            raise ValueError(f"period_s must be > 0, got {period_s}")
        self.source_name = name
        self.backend = backend
        self.model = model
        self.mount = mount or MountPose()
        self.period_s = period_s
        self.rng = np.random.default_rng(seed)
        self.read_errors = 0
        """Reads a real sensor failed (bus errors), each skipping one sample."""

    async def run(self) -> None:
        pub = self.publisher(RANGE, self.source_name,
                             period_s=self.period_s)
        limits = {"model": self.model.name, "min_mm": round(self.model.min_range_m * 1000),
                  "max_mm": round(self.model.max_range_m * 1000)}
        measured, blocking = self.backend.measured, self.backend.blocking
        async for stamp in every(self.bus.clock, self.period_s):
            try:
                if blocking:  # a bus transaction: off the loop
                    distance_m = await asyncio.to_thread(
                        self.backend.distance_m, self.mount, max_range_m=self.model.max_range_m)
                else:
                    distance_m = self.backend.distance_m(self.mount,
                                                         max_range_m=self.model.max_range_m)
            except RangeReadError as exc:
                self.read_errors += 1
                if throttle.first_and_every(self.read_errors):
                    log.warning("%s: cannot read the sensor (%d failed reads so far): %s",
                                self.name, self.read_errors, exc)
                continue
            reading = (limit_ir(self.model, distance_m) if measured
                       else read_ir(self.model, distance_m, rng=self.rng))
            pub.publish({"range_mm": reading.range_mm, "status": str(reading.status), **limits},
                        stamp_ns=stamp)


ModelName = Literal["ir-4-30", "ir-10-80", "ir-20-150"]
"""The thesis's IR models by range in cm (the keys of :data:`components.range.ir.IR_MODELS`)."""


def build_device(
    *,
    bus: Bus,
    name: str,
    backend: RangeBackend,
    model: ModelName = "ir-10-80",
    x_m: float = 0.05,
    y_m: float = 0.0,
    yaw_deg: Annotated[float, msgspec.Meta(ge=-180, le=180)] = 0.0,
    period_s: Annotated[float, msgspec.Meta(gt=0)] = 0.04,
    seed: int = 0,
) -> RangeComponent:
    """The ``range`` device kind: one IR range finder publishing ``sensor/range/<name>``.

    ``model``: a thesis model by range in cm; a backend that reads a given model (its
    ``model``, e.g. ``range.ads1115``'s ``sensor``) must read this one. Mount in the robot
    frame (REP-103): ``x_m`` ahead of the robot's centre, ``y_m`` to its left, ``yaw_deg``
    the beam's direction, + to the left of straight ahead. ``period_s``: time between
    readings (robot clock). ``seed`` (the run's, injected) seeds the model's 5–10 % error.
    """
    measures = backend.model
    if measures is not None and measures != model:
        # The backend reads one model's curve, the device applies this model's limits: a
        # reading of the one judged by the other's range would be wrong without a sign.
        raise ConfigurationError(
            f"range {name!r}: its backend reads model {measures} but the device's model is "
            f"{model}: give both the same model (backend_params sensor, params model)")
    mount = MountPose(x_m=x_m, y_m=y_m, yaw_rad=math.radians(yaw_deg))
    return RangeComponent(bus=bus, backend=backend, name=name, model=IR_MODELS[model],
                          mount=mount, period_s=period_s, seed=seed)
