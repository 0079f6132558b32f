"""What the motors component drives: anything that accepts two PWM pulse widths."""

from __future__ import annotations

from ubf_async.assembly.backend import Backend

__all__ = ["MotorBackend"]


class MotorBackend(Backend):
    """Hardware (or simulated) motor driver.

    The HAL has already mapped speed/turn to pulse widths and compensated each motor with its
    calibration table; the backend applies them as they are.

    ``hold_s`` (seconds): how long the init pulse and the stop pulse must stay on its pins for
    the motor controllers to see them — for a backend driving real PWM outputs
    :data:`components.motors.pwm.HOLD_PERIODS` periods, 0 for one that applies a pulse at once
    (the simulator's). The motors component holds each that long — awaiting, never blocking
    the event loop — before the next pulse and before the backend is closed.
    """

    hold_s: float

    def apply_pulses(self, *, left_ms: float, right_ms: float) -> None:
        """Set the high time of the 20 ms PWM period for each motor, in milliseconds."""
        raise NotImplementedError
