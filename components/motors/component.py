"""The motors component: ``cmd/drive`` in, PWM pulses out, with a command watchdog.

* Subscribes to ``ubf/<robot>/cmd/drive`` (newest command only). A malformed command is
  rejected and counted, never applied; values beyond ±100 are clamped (the protocol already
  refuses non-finite ones).
* Maps speed/turn to per-motor pulse widths through each motor's calibration table and
  applies them through its :class:`~components.motors.backend.MotorBackend`.
* **Watchdog:** if no valid drive command has arrived for ``timeout_s`` (default
  :data:`DEFAULT_TIMEOUT_S`, 110 ms), it applies the stop pulse — a controller that dies
  cannot leave the robot driving. The deadline follows
  :class:`~ubf_async.clocks.clock.SilenceLimit`: ``timeout_s`` of robot time, or — when the robot
  clock's source has gone silent (a simulator that died, not one holding time on purpose) —
  ``max(timeout_s, 0.5 s)`` of wall time. A new simulation run (the clock reset) also stops
  the wheels: a command of the old run does not hold in the new one.

  Why 110 ms: the goal is that the wheels stop at most :data:`STOP_GOAL_S` (200 ms) after
  the last command was *sent*. Two failures bound the timeout ``T``: a late stop, when
  ``T`` + the delivery and wake-up lag exceeds the goal, and a spurious stop, when a 50 Hz
  controller's command period (20 ms) + the same lag exceeds ``T``. ``T = (200 + 20) / 2``
  leaves both 90 ms of lag; the watchdog sleeps until the exact deadline (no polling), so
  on an idle host the stop comes ≈ ``T`` + 1–2 ms after the last command
  (``python -m bench.margins`` measures it end to end).
* **Start and close:** the init pulse arms the drivers, then the stop pulse; closing (or a
  failure of the run) applies the stop pulse. A real backend's ``hold_s`` (two PWM periods,
  :data:`~components.motors.pwm.HOLD_PERIODS`) is awaited after the init pulse and after the
  closing stop pulse, so that the backend is closed (its pins released) only once the drivers
  have seen whole periods of it; the wait never blocks the event loop, and a second
  cancellation does not cut it short.
* Publishes what it applied on ``ubf/<robot>/sensor/motors/<name>`` (schema
  ``motors.applied``), including each wheel's commanded direction, which the encoders use.
"""

from __future__ import annotations

import asyncio
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
    body_calibrations,
    clamp_drive,
    pulse_widths,
)
from ubf_async.assembly.body import DEFAULT_BODY, BodySpec
from ubf_async.clocks.clock import SilenceLimit, sleep_until
from ubf_async.runtime.bus import Bus
from ubf_async.runtime.component import Component
from ubf_async.wire.protocol import Message
from ubf_async.wire.topics import DRIVE, MOTORS, Drive

__all__ = ["DEFAULT_TIMEOUT_S", "STOP_GOAL_S", "MotorTrim", "MotorsComponent", "build_device"]

log = logging.getLogger(__name__)

DEFAULT_TIMEOUT_S = 0.11
"""The command watchdog's default timeout (see the module docstring for the choice)."""
STOP_GOAL_S = 0.2
"""How soon after the last command is sent the wheels must have stopped, end to end."""


class MotorsComponent(Component):
    def __init__(
        self,
        *,
        bus: Bus,
        backend: MotorBackend,
        name: str = "main",
        timeout_s: float = DEFAULT_TIMEOUT_S,
        left: MotorCalibration = DEFAULT_LEFT_CALIBRATION,
        right: MotorCalibration = DEFAULT_RIGHT_CALIBRATION,
        turn_gain: float = 1.0,
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
        if not 0.0 < turn_gain <= 1.0:
            raise ValueError(f"turn_gain must be in (0, 1], got {turn_gain}")
        self.turn_gain = turn_gain
        """The body's share of the wheels' difference a turn of 100 gets (``body.turn_gain``)."""
        self.malformed: dict[str, int] = {}
        self.clamped = 0
        self.timeouts = 0
        self.ignored = 0
        """Drive commands that arrived while the stop pulse was held on closing: not applied."""
        self.applied: PulseCommand | None = None
        self.stopped_by_watchdog = True
        self.limit = SilenceLimit(limit_s=timeout_s)
        self._last_command_ns: int | None = None
        self._last_command_wall_ns = 0
        self._command_resets = 0
        self._armed = asyncio.Event()
        self._stopping = False

    async def run(self) -> None:
        keys = self.bus.keys
        self._applied_pub = self.publisher(MOTORS, self.source_name)
        self._stopping = False
        try:
            # Arm the drivers with the init pulse (inside both dead zones), held for whole
            # periods so that they see it, then hold still.
            self.backend.apply_pulses(left_ms=DEFAULT_PWM.init_ms, right_ms=DEFAULT_PWM.init_ms)
            await self._hold()
            self._apply(0.0, 0.0, reason="init")
            self.stopped_by_watchdog = True
            self.subscribe_topic(DRIVE.key(keys), DRIVE, self._on_drive, self.malformed)
            await self._guard()
        finally:  # closed (SIGTERM, Ctrl-C, the run's end) or failed: the wheels stop
            self._stopping = True  # a command arriving during the hold must not move them
            self.stopped_by_watchdog = True
            self._apply(0.0, 0.0, reason="stopped")
            # The backend is closed (its pins released) only after this: hold the stop pulse
            # for whole periods first, even if a second cancellation arrives meanwhile.
            await self._hold(through_cancel=True)

    async def _hold(self, *, through_cancel: bool = False) -> None:
        """Wait the backend's ``hold_s`` (wall time: the pins do not run on simulated time)
        without blocking the loop. With ``through_cancel`` a cancellation waits for the end
        of the hold (at most ``hold_s``) and is raised after it."""
        hold_s = self.backend.hold_s
        if hold_s <= 0:
            return
        loop = asyncio.get_running_loop()
        deadline = loop.time() + hold_s
        cancelled: asyncio.CancelledError | None = None
        while (left := deadline - loop.time()) > 0:
            try:
                await asyncio.sleep(left)
            except asyncio.CancelledError as exc:
                if not through_cancel:
                    raise
                cancelled = exc
        if cancelled is not None:
            raise cancelled

    async def _guard(self) -> None:
        """The watchdog: stop the wheels when commands stop coming."""
        clock = self.bus.clock
        timeout_ns = round(self.timeout_s * 1e9)
        while True:
            last = self._last_command_ns
            if last is None or self.stopped_by_watchdog:
                self._armed.clear()
                await self._armed.wait()  # nothing to guard until a command arrives
                continue
            if clock.resets != self._command_resets:
                self._stop("clock_reset", "the clock was reset to a new run")
                continue
            overdue = self.limit.overdue(clock, since_ns=last,
                                         since_wall_ns=self._last_command_wall_ns)
            if overdue is not None:
                self._stop("timeout", f"no drive command for {overdue}")
                continue
            # Re-checked on waking: a newer command moves both deadlines.
            wall_deadline = self.limit.wall_deadline_ns(
                clock, since_wall_ns=self._last_command_wall_ns)
            await sleep_until(clock, last + timeout_ns, wall_deadline_ns=wall_deadline)

    def _stop(self, reason: str, why: str) -> None:
        self.timeouts += 1
        self.stopped_by_watchdog = True
        log.warning("%s: stopping", why)
        self._apply(0.0, 0.0, reason=reason)

    def _on_drive(self, key: str, message: Message[Drive], received_ns: int) -> None:
        if self._stopping:
            self.ignored += 1
            return
        speed, turn = message.data.speed, message.data.turn
        safe_speed, safe_turn = clamp_drive(speed, turn)
        if (safe_speed, safe_turn) != (speed, turn):
            self.clamped += 1
        clock = self.bus.clock
        self._last_command_ns = clock.now_ns()
        self._last_command_wall_ns = received_ns
        self._command_resets = clock.resets
        self.stopped_by_watchdog = False
        self._armed.set()
        self._apply(safe_speed, safe_turn, reason="command")

    def _apply(self, speed: float, turn: float, *, reason: str) -> None:
        # The body's turn gain: the same turn command, the same turn rate on any body.
        command = pulse_widths(speed, turn * self.turn_gain, left=self.left, right=self.right)
        self.backend.apply_pulses(left_ms=command.left_ms, right_ms=command.right_ms)
        self.applied = command
        self._applied_pub.publish({
            "speed": speed, "turn": turn,
            "left_ms": command.left_ms, "right_ms": command.right_ms,
            "left_dir": command.left_direction, "right_dir": command.right_direction,
            "reason": reason,
        })


class MotorTrim(msgspec.Struct, kw_only=True, forbid_unknown_fields=True):
    """One motor's calibration, as a robot file gives it (``docs/hardware.md``): the pulse it
    stands still at, its dead zone ``[lo, hi]`` (any wheel command ≠ 0 starts from its edge,
    so it always moves the wheel) and the pulses of full reverse and full forward; between
    them the pulse grows linearly with the wheel command."""

    zero_ms: Annotated[float, msgspec.Meta(ge=0.5, le=2.5)]
    dead_zone_ms: tuple[Annotated[float, msgspec.Meta(ge=0.5, le=2.5)],
                        Annotated[float, msgspec.Meta(ge=0.5, le=2.5)]]
    reverse_ms: Annotated[float, msgspec.Meta(ge=0.5, le=2.5)] = DEFAULT_PWM.min_ms
    forward_ms: Annotated[float, msgspec.Meta(ge=0.5, le=2.5)] = DEFAULT_PWM.max_ms

    def __post_init__(self) -> None:
        self.calibration()  # refuse an inconsistent table when the robot file loads

    def calibration(self) -> MotorCalibration:
        lo, hi = self.dead_zone_ms
        if not lo <= self.zero_ms <= hi:
            raise ValueError(f"zero_ms {self.zero_ms} lies outside dead_zone_ms [{lo}, {hi}]")
        return MotorCalibration(
            points=((-100.0, self.reverse_ms), (0.0, self.zero_ms), (100.0, self.forward_ms)),
            breakaway_ms=(lo, hi))


def build_device(
    *,
    bus: Bus,
    name: str,
    backend: MotorBackend,
    timeout_s: Annotated[float, msgspec.Meta(gt=0)] = DEFAULT_TIMEOUT_S,
    left: MotorTrim | None = None,
    right: MotorTrim | None = None,
    body: BodySpec = DEFAULT_BODY,
) -> MotorsComponent:
    """The ``motors`` device kind: ``cmd/drive`` → PWM through ``backend``, stopping the
    wheels when no drive command arrived for ``timeout_s`` (robot clock; also in wall time
    when the clock's source goes silent, see :class:`~ubf_async.clocks.clock.SilenceLimit`) and
    when it closes.
    ``left`` / ``right``: each motor's calibration (:class:`MotorTrim`); default: the one
    that inverts the body's motors (``body``, the robot file's, injected: for the Mini-WHEGS
    the thesis's measured motors)."""
    left_default, right_default = body_calibrations(body)
    return MotorsComponent(
        bus=bus, backend=backend, name=name, timeout_s=timeout_s,
        left=left.calibration() if left is not None else left_default,
        right=right.calibration() if right is not None else right_default,
        turn_gain=body.turn_gain)
