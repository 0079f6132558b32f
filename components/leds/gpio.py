"""``leds.gpio``: LEDs on GPIO pins, via gpiozero — bit ``i`` of the mask lights ``pins[i]``.

Each LED is a gpiozero :class:`~gpiozero.LED` (a digital output) on the process's pin factory
(:func:`components.hardware.pin_factory`, shared with the motors and encoders). An LED wired
from the pin through its resistor to ground lights when the pin is high (``active_high``, the
default); one wired from 3.3 V into the pin lights when it is low (``active_high: false``).

Setting a pin is a register write (on lgpio one ioctl, microseconds), so :meth:`set_leds`
runs where the LED component calls it, on the event loop, as the backend contract allows.
Closing turns every LED off and releases the pins; the LED component turns them off first too
(all off on start and when it closes).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Annotated, Any, ClassVar

import msgspec

from components import hardware
from components.hardware import Pin, PinFactoryName
from components.leds.backend import LedBackend
from components.leds.bank import MAX_LEDS
from ubf_async.assembly.context import DeviceContext

__all__ = ["GpioLedBackend", "gpio_backend"]


class GpioLedBackend(LedBackend):
    """One gpiozero LED per pin, LED ``i`` on ``pins[i]``."""

    physical: ClassVar[bool] = True

    def __init__(self, *, pins: Sequence[str], factory: Any, active_high: bool = True) -> None:
        if not 1 <= len(pins) <= MAX_LEDS:
            raise ValueError(f"give 1 to {MAX_LEDS} pins, got {len(pins)}")
        for i, pin in enumerate(pins):
            if pin in pins[:i]:
                raise ValueError(f"pin {pin!r} is given for LEDs {pins.index(pin)} and {i}")
        from gpiozero import LED

        self.count = len(pins)
        self._leds: list[Any] = []
        try:
            for pin in pins:
                self._leds.append(LED(pin, active_high=active_high, initial_value=False,
                                      pin_factory=factory))
        except Exception:
            self.close()  # the pins already had
            raise

    def set_leds(self, mask: int) -> None:
        for i, led in enumerate(self._leds):
            if not led.closed:  # after close: nothing left to light
                led.value = bool(mask >> i & 1)

    def close(self) -> None:
        """Every LED off and its pin released; calling it again does nothing."""
        for led in self._leds:
            if not led.closed:
                led.off()
                led.close()


def gpio_backend(
    *,
    context: DeviceContext,
    pins: Annotated[list[Pin], msgspec.Meta(min_length=1, max_length=MAX_LEDS)],
    active_high: bool = True,
    pin_factory: PinFactoryName | None = None,
) -> GpioLedBackend:
    """``leds.gpio``: LED ``i`` on ``pins[i]`` (gpiozero pin names, e.g. ``GPIO17``), lit
    when its pin is high (``active_high``, an LED from the pin to ground) or low (false: an
    LED from 3.3 V into the pin); ``pin_factory`` as for ``motors.gpio``. The device's
    ``count`` is the number of pins."""
    return hardware.on_pins("leds.gpio", pin_factory, lambda factory: GpioLedBackend(
        pins=pins, factory=factory, active_high=active_high))


gpio_backend.requires_simulator = None  # type: ignore[attr-defined]
