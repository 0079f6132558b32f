"""What the LED component drives: anything that lights LEDs from a bit mask."""

from __future__ import annotations

from typing import ClassVar

from ubf_async.assembly.backend import Backend

__all__ = ["LedBackend"]


class LedBackend(Backend):
    physical: ClassVar[bool] = False
    """True for a backend that lights LEDs someone can watch (bring-up blinks them); False
    (the default): LEDs in memory."""
    count: int | None = None
    """How many LEDs the backend drives (``leds.gpio``: its pins), which the device's count
    must then be; None (the default): any."""

    def set_leds(self, mask: int) -> None:
        """Light exactly the LEDs whose bits are set (bit ``i`` = LED ``i``); non-blocking."""
        raise NotImplementedError
