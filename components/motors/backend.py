"""What the motors component drives: anything that accepts two PWM pulse widths."""

from __future__ import annotations

from typing import Protocol


class MotorBackend(Protocol):
    """Hardware (or simulated) motor driver.

    The HAL has already mapped speed/turn to pulse widths and compensated each motor with its
    calibration table; the backend applies them as they are.
    """

    def apply_pulses(self, *, left_ms: float, right_ms: float) -> None:
        """Set the high time of the 20 ms PWM period for each motor, in milliseconds."""
        ...
