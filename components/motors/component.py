"""The motors component: ``cmd/drive`` in, PWM pulses out, with a command watchdog.

* Subscribes to ``ubf/<robot>/cmd/drive`` (newest command only). A malformed command is
  rejected and counted, never applied; values beyond ±100 are clamped (the protocol already
  refuses non-finite ones).
* Maps speed/turn to per-motor pulse widths through each motor's calibration table and
  applies them through its :class:`~components.motors.backend.MotorBackend`.
* **Watchdog:** if no valid drive command has arrived for ``timeout_s`` (robot clock,
  default 200 ms), it applies the stop pulse — a controller that dies cannot leave the
  robot driving.
* Publishes what it applied on ``ubf/<robot>/sensor/motors/<name>`` (schema
  ``motors.applied``), including each wheel's commanded direction, which the encoders use.
"""

from __future__ import annotations

import logging
from typing import Annotated

import msgspec

from components.motors.backend import MotorBackend
from components.motors.pwm import (
    DEFAULT_LEFT_CALIBRATION,
    DEFAULT_PWM,
    DEFAULT_RIGHT_CALIBRATION,
    MotorCalibration,
    PulseCommand,
    clamp_command,
    pulse_widths,
)
from ubf_async.bus import Bus, decode_or_count
from ubf_async.component import Component

log = logging.getLogger(__name__)


class MotorsComponent(Component):
    def __init__(
        self,
        *,
        bus: Bus,
        backend: MotorBackend,
        name: str = "main",
        timeout_s: float = 0.2,
        left: MotorCalibration = DEFAULT_LEFT_CALIBRATION,
        right: MotorCalibration = DEFAULT_RIGHT_CALIBRATION,
        **component_options: float,
    ) -> None:
        super().__init__(bus=bus, name=f"motors-{name}", **component_options)
        self.source_name = name
        if not timeout_s > 0:
            raise ValueError(f"timeout_s must be > 0, got {timeout_s}")
        self.backend = backend
        self.timeout_s = timeout_s
        self.left = left
        self.right = right
        self.malformed: dict[str, int] = {}
        self.clamped = 0
        self.timeouts = 0
        self.applied: PulseCommand | None = None
        self.stopped_by_watchdog = True
        self._last_command_ns: int | None = None

    async def run(self) -> None:
        keys = self.bus.keys
        self._applied_pub = self.publisher(
            keys.sensor("motors", self.source_name), "motors.applied"
        )
        # Arm the drivers with the init pulse (inside both dead zones), then hold still.
        self.backend.apply_pulses(left_ms=DEFAULT_PWM.init_ms, right_ms=DEFAULT_PWM.init_ms)
        self._apply(0.0, 0.0, reason="init")
        self.subscribe(keys.cmd("drive"), self._on_drive)
        clock = self.bus.clock
        timeout_ns = int(self.timeout_s * 1e9)
        while True:
            last = self._last_command_ns
            if last is None or self.stopped_by_watchdog:
                await clock.sleep(self.timeout_s / 4)  # nothing to guard until a command
                continue
            now = clock.now_ns()
            if now - last >= timeout_ns:
                self.timeouts += 1
                self.stopped_by_watchdog = True
                log.warning("no drive command for %.0f ms: stopping", (now - last) / 1e6)
                self._apply(0.0, 0.0, reason="timeout")
                continue
            await clock.sleep_until_ns(last + timeout_ns)  # re-checked: a newer command moves it

    def _on_drive(self, key: str, payload: bytes, received_ns: int) -> None:
        message = decode_or_count(payload, self.malformed, key, schema="drive")
        if message is None:
            return
        speed, turn = message.data["speed"], message.data["turn"]
        safe_speed, safe_turn = clamp_command(speed, turn)
        if (safe_speed, safe_turn) != (speed, turn):
            self.clamped += 1
        self._last_command_ns = self.bus.clock.now_ns()
        self.stopped_by_watchdog = False
        self._apply(safe_speed, safe_turn, reason="command")

    def _apply(self, speed: float, turn: float, *, reason: str) -> None:
        command = pulse_widths(speed, turn, left=self.left, right=self.right)
        self.backend.apply_pulses(left_ms=command.left_ms, right_ms=command.right_ms)
        self.applied = command
        self._applied_pub.publish({
            "speed": speed, "turn": turn,
            "left_ms": command.left_ms, "right_ms": command.right_ms,
            "left_dir": command.left_direction, "right_dir": command.right_direction,
            "reason": reason,
        })


def build_device(
    *,
    bus: Bus,
    name: str,
    backend: MotorBackend,
    timeout_s: Annotated[float, msgspec.Meta(gt=0)] = 0.2,
) -> MotorsComponent:
    """The ``motors`` device kind: ``cmd/drive`` → PWM through ``backend``, stopping the
    wheels when no drive command arrived for ``timeout_s`` (robot clock)."""
    return MotorsComponent(bus=bus, backend=backend, name=name, timeout_s=timeout_s)
