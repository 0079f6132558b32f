"""``motors.gpio``: the thesis's servo-style pulses on two real PWM outputs, via gpiozero.

Each motor controller gets a ``period_ms`` (20 ms) PWM signal whose high time is the pulse the
HAL computed (1.0–2.0 ms, calibrated per motor): gpiozero's
:class:`~gpiozero.PWMOutputDevice` at ``1000 / period_ms`` Hz with duty cycle
``pulse_ms / period_ms``, on any pin factory (lgpio and pigpio time pulses in hardware or a
daemon; see ``docs/hardware.md``). A pulse outside ``[min_ms, max_ms]`` is clipped to it and
counted: nothing beyond full reverse/forward ever reaches a controller.

Stopping: the motors component applies its calibrated stop pulses on start (after the init
pulse), on the watchdog and when it closes, whatever ended the process (exception, SIGTERM,
Ctrl-C all close it). The init pulse and the closing stop pulse are held for
:data:`~components.motors.pwm.HOLD_PERIODS` whole periods (:attr:`GpioMotorBackend.hold_s`,
40 ms at 20 ms) before the next pulse or the release. Closing the backend then releases the
pins, which ends the pulses; a servo-style speed controller without pulses holds still.
gpiozero's own exit handler releases the pins if the process ends any other way short of
``SIGKILL``.

Who holds: :meth:`GpioMotorBackend.close` releases at once and never waits. It is called from
the motors component's close, on the event loop, where a 40 ms blocking wait would stall every
other component of the process; the component awaits the hold before it closes the backend.
Code off the loop (the wiring check, a script) holds with a plain sleep of ``hold_s``.
"""

from __future__ import annotations

import logging
import threading
from typing import Annotated, Any

import msgspec

from components import hardware
from components.hardware import Pin, PinFactoryName
from components.motors.backend import MotorBackend
from components.motors.pwm import DEFAULT_PWM, hold_s
from ubf_async.assembly.context import DeviceContext

__all__ = ["GpioMotorBackend", "Pin", "gpio_backend"]

log = logging.getLogger(__name__)


class GpioMotorBackend(MotorBackend):
    """Two PWM outputs (left, right) carrying servo-style pulses."""

    def __init__(self, *, left_pin: str, right_pin: str, factory: Any,
                 period_ms: float = DEFAULT_PWM.period_ms, min_ms: float = DEFAULT_PWM.min_ms,
                 max_ms: float = DEFAULT_PWM.max_ms) -> None:
        if left_pin == right_pin:
            raise ValueError(f"left_pin and right_pin are both {left_pin!r}")
        if not 0 < min_ms < max_ms <= period_ms:
            raise ValueError(f"need 0 < min_ms < max_ms <= period_ms, got {min_ms}, {max_ms}, "
                             f"{period_ms}")
        from gpiozero import PWMOutputDevice

        self.period_ms = period_ms
        self.hold_s = hold_s(period_ms)
        """How long the init and stop pulses stay on the pins (two whole periods)."""
        self.min_ms = min_ms
        self.max_ms = max_ms
        self.clipped = 0
        """Pulses outside ``[min_ms, max_ms]`` that were clipped."""
        self.last_ms: tuple[float, float] | None = None
        self._lock = threading.Lock()
        frequency = 1000.0 / period_ms
        self._left = PWMOutputDevice(left_pin, frequency=frequency, initial_value=0.0,
                                     pin_factory=factory)
        try:
            self._right = PWMOutputDevice(right_pin, frequency=frequency, initial_value=0.0,
                                          pin_factory=factory)
        except Exception:
            self._left.close()
            raise

    def apply_pulses(self, *, left_ms: float, right_ms: float) -> None:
        left = self._safe(left_ms)
        right = self._safe(right_ms)
        with self._lock:
            if self._left.closed:
                return
            self._left.value = left / self.period_ms
            self._right.value = right / self.period_ms
            self.last_ms = (left, right)

    def _safe(self, pulse_ms: float) -> float:
        if not self.min_ms <= pulse_ms <= self.max_ms:  # also False for NaN
            self.clipped += 1
            log.warning("pulse %r ms outside [%g, %g] ms: clipped", pulse_ms, self.min_ms,
                        self.max_ms)
            return self.max_ms if pulse_ms > self.max_ms else self.min_ms
        return pulse_ms

    def close(self) -> None:
        """Release both pins (the pulses end) at once; calling it again does nothing.

        It does not wait: hold the stop pulse for :attr:`hold_s` first (the module docstring
        says why the caller holds)."""
        with self._lock:
            for device in (self._left, self._right):
                device.close()


def gpio_backend(
    *,
    context: DeviceContext,
    left_pin: Pin,
    right_pin: Pin,
    pin_factory: PinFactoryName | None = None,
    period_ms: Annotated[float, msgspec.Meta(gt=0, le=100)] = DEFAULT_PWM.period_ms,
) -> GpioMotorBackend:
    """``motors.gpio``: servo-style pulses on ``left_pin`` and ``right_pin`` (gpiozero pin
    names, e.g. ``GPIO12``) every ``period_ms``; ``pin_factory`` picks gpiozero's pin
    factory (``lgpio``, ``pigpio``, ``rpigpio``, ``native``, ``mock``; default: gpiozero's
    choice, ``GPIOZERO_PIN_FACTORY``)."""
    return hardware.on_pins("motors.gpio", pin_factory, lambda factory: GpioMotorBackend(
        left_pin=left_pin, right_pin=right_pin, factory=factory, period_ms=period_ms))


gpio_backend.requires_simulator = None  # type: ignore[attr-defined]
