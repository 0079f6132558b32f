"""A bank of on/off LEDs as a bit mask: the thesis HAL's LED access functions (pure logic).

Bit ``i`` of the mask is LED ``i`` (LED 0 is bit 0). A bank has ``count`` LEDs (1–8); a mask
with bits beyond them is refused by :meth:`LedBank.check` or cut to the bank by
:meth:`LedBank.fit`, which says how many bits it dropped.
"""

from __future__ import annotations

__all__ = ["MAX_LEDS", "LedBank"]

MAX_LEDS = 8
"""The most LEDs a bank drives (the action's ``leds`` is one byte)."""


class LedBank:
    """Which of ``count`` LEDs are lit."""

    def __init__(self, *, count: int, mask: int = 0) -> None:
        if isinstance(count, bool) or not isinstance(count, int) or not 1 <= count <= MAX_LEDS:
            raise ValueError(f"an LED bank has 1 to {MAX_LEDS} LEDs, got {count!r}")
        self.count = count
        self.mask = self.check(mask)

    @property
    def all_mask(self) -> int:
        """Every LED of the bank lit."""
        return (1 << self.count) - 1

    def fit(self, mask: int) -> tuple[int, int]:
        """``mask`` cut to this bank, and the number of bits it had beyond it."""
        if isinstance(mask, bool) or not isinstance(mask, int) or not 0 <= mask <= 255:
            raise ValueError(f"an LED mask is an integer 0..255, got {mask!r}")
        return mask & self.all_mask, bin(mask & ~self.all_mask).count("1")

    def check(self, mask: int) -> int:
        """``mask`` if it lights only LEDs of this bank; else ``ValueError``."""
        fitted, dropped = self.fit(mask)
        if dropped:
            raise ValueError(f"mask {mask:#04x} lights LEDs beyond the bank's {self.count}")
        return fitted

    def _index(self, led: int) -> int:
        if isinstance(led, bool) or not isinstance(led, int) or not 0 <= led < self.count:
            raise IndexError(f"LED {led!r}: this bank has LEDs 0..{self.count - 1}")
        return led

    def set_all(self, mask: int) -> None:
        """Light exactly the LEDs of ``mask``."""
        self.mask = self.check(mask)

    def on(self, led: int) -> None:
        self.mask |= 1 << self._index(led)

    def off(self, led: int) -> None:
        self.mask &= ~(1 << self._index(led))

    def toggle(self, led: int) -> None:
        self.mask ^= 1 << self._index(led)

    def is_on(self, led: int) -> bool:
        return bool(self.mask >> self._index(led) & 1)

    def lit(self) -> list[int]:
        """The lit LEDs' numbers, lowest first."""
        return [i for i in range(self.count) if self.mask >> i & 1]
