"""What the LED component drives: anything that lights LEDs from a bit mask."""

from __future__ import annotations

from ubf_async.assembly.backend import Backend

__all__ = ["LedBackend"]


class LedBackend(Backend):
    def set_leds(self, mask: int) -> None:
        """Light exactly the LEDs whose bits are set (bit ``i`` = LED ``i``); non-blocking."""
        raise NotImplementedError
