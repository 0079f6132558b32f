"""The LED component: ``cmd/leds`` in, lit LEDs out.

* Subscribes to ``ubf/<robot>/cmd/leds`` (schema ``leds``; newest command only). A malformed
  command is rejected and counted; bits beyond the bank's ``count`` LEDs are dropped and
  counted (``clamped``), never passed on.
* Lights the LEDs through its :class:`~components.leds.backend.LedBackend`; all off on start
  and when it closes.
* Publishes what is lit on ``sensor/leds/<name>`` (schema ``leds.state``) on every change and
  every ``period_s`` (robot clock), so the state, the status line and recordings show it.
"""

from __future__ import annotations

from typing import Annotated

import msgspec

from components.leds.backend import LedBackend
from components.leds.bank import MAX_LEDS, LedBank
from ubf_async.clocks.clock import every
from ubf_async.errors import ConfigurationError
from ubf_async.runtime.bus import Bus
from ubf_async.runtime.component import Component
from ubf_async.wire.protocol import Message
from ubf_async.wire.topics import LED_STATE, LEDS, Leds

__all__ = ["DEFAULT_COUNT", "LedsComponent", "build_device"]

DEFAULT_COUNT = 2
"""LEDs in a bank whose count neither the robot file nor the backend says (the thesis's
robot's two)."""


class LedsComponent(Component):
    def __init__(self, *, bus: Bus, backend: LedBackend, name: str = "panel",
                 count: int = DEFAULT_COUNT, period_s: float = 0.5,
                 **component_options: float) -> None:
        super().__init__(bus=bus, name=f"leds-{name}", **component_options)
        if not period_s > 0:
            raise ValueError(f"period_s must be > 0, got {period_s}")
        self.source_name = name
        self.backend = backend
        self.bank = LedBank(count=count)
        self.period_s = period_s
        self.malformed: dict[str, int] = {}
        self.clamped = 0
        """Commands that lit LEDs beyond the bank (those bits were dropped)."""

    async def run(self) -> None:
        self._pub = self.publisher(LED_STATE, self.source_name, period_s=self.period_s)
        self._light(0)
        self.subscribe_topic(LEDS.key(self.bus.keys), LEDS, self._on_leds, self.malformed)
        try:
            async for _ in every(self.bus.clock, self.period_s):
                self._publish()  # repeated, so the source never goes stale
        finally:
            self._light(0)
            self._publish()

    def _on_leds(self, key: str, message: Message[Leds], received_ns: int) -> None:
        mask, dropped = self.bank.fit(message.data.mask)
        if dropped:
            self.clamped += 1
        if mask != self.bank.mask:
            self._light(mask)
            self._publish()

    def _light(self, mask: int) -> None:
        self.bank.set_all(mask)
        self.backend.set_leds(mask)

    def _publish(self) -> None:
        self._pub.publish({"mask": self.bank.mask, "count": self.bank.count})


def build_device(
    *,
    bus: Bus,
    name: str,
    backend: LedBackend,
    count: Annotated[int, msgspec.Meta(ge=1, le=MAX_LEDS)] | None = None,
    period_s: Annotated[float, msgspec.Meta(gt=0)] = 0.5,
) -> LedsComponent:
    """The ``leds`` device kind: ``count`` LEDs lit from ``cmd/leds`` through ``backend``;
    what is lit is published on ``sensor/leds/<name>`` on each change and every
    ``period_s`` (robot clock). ``count`` left out: as many as the backend drives (a
    ``gpio`` backend's pins), else 2; given, a backend that drives a number of LEDs must
    drive that many."""
    drives = backend.count
    if count is not None and drives is not None and count != drives:
        # A bit with no LED behind it, or an LED no bit lights: either way a command would
        # not show as it says.
        raise ConfigurationError(f"leds {name!r}: its backend drives {drives} LEDs (its pins) "
                                 f"but the device's count is {count}: give as many pins as "
                                 f"LEDs, or leave count out")
    return LedsComponent(bus=bus, backend=backend, name=name,
                         count=count if count is not None else drives or DEFAULT_COUNT,
                         period_s=period_s)
