"""The IR range-finder component: one sensor of a thesis model at a mounting pose.

Every ``period_s`` (robot clock) it asks its backend for the true distance along the beam,
applies the model's range limits and 5–10 % error (:func:`components.range.ir.read_ir`) and
publishes ``sensor/range/<name>`` (schema ``range``): ``range_mm`` and ``status`` — out of
range is reported as ``too_close``/``too_far`` with ``range_mm`` nil, never as a number.
"""

from __future__ import annotations

import numpy as np

from components.range.backend import MountPose, RangeBackend
from components.range.ir import GP2Y0A21, IrModel, read_ir
from ubf_async.bus import Bus
from ubf_async.clock import every
from ubf_async.component import Component


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

    async def run(self) -> None:
        pub = self.publisher(self.bus.keys.sensor("range", self.source_name), "range",
                             period_s=self.period_s)
        limits = {"model": self.model.name, "min_mm": round(self.model.min_range_m * 1000),
                  "max_mm": round(self.model.max_range_m * 1000)}
        async for stamp in every(self.bus.clock, self.period_s):
            true_m = self.backend.distance_m(self.mount, max_range_m=self.model.max_range_m)
            reading = read_ir(self.model, true_m, rng=self.rng)
            pub.publish({"range_mm": reading.range_mm, "status": str(reading.status), **limits},
                        stamp_ns=stamp)
