"""``encoders.gpio``: quadrature A/B edges of both wheel encoders from GPIO, via gpiozero.

Each of the four lines (left A/B, right A/B) is a gpiozero input pin with edge detection on
both edges. The pin factory calls back on its own thread for every edge (lgpio stamps each
edge in the kernel; its ``ticks`` travel with it): the callback only records the wheel's new
2-bit state ``(A << 1) | B`` and the edge's time in a bounded buffer under a lock, so edges are
never handled on the event loop. The encoders component takes the batch every ``period_s``
(:meth:`GpioEncoderBackend.read_phases`) and decodes it with the existing
:class:`~components.quadrature.QuadratureDecoder`, in either direction mode.

A buffer that fills between two reads (more than ``max_pending`` edges: a component stalled
for a long time) drops the oldest edges and counts them in ``overflowed`` (the encoders
component publishes it as ``dropped``); the decoder then sees a jump, which it counts as an
error rather than guessing, or — when a multiple of four edges was dropped — a valid step,
which is why the count of dropped edges is the number to watch.

Edge times: each batch's :class:`~components.encoders.backend.EdgeTiming` (``edge_timing``)
says how long its edges took, from the edges' own stamps — differences only, through the pin
factory's ``ticks_diff`` (the stamps' clock differs between factories and kernels; pigpio's
wraps). The encoders component divides each wheel's decoded edges by it: the wheel's speed,
finer than counting edges per period at low speed, where a period holds a few edges or none.
"""

from __future__ import annotations

import logging
import threading
from collections import deque
from typing import Any, Literal

import numpy as np

from components import hardware
from components.encoders.backend import EdgeTiming, EncoderBackend
from components.hardware import Pin, PinFactoryName
from ubf_async.assembly.context import DeviceContext

__all__ = ["MAX_EDGE_GAP_S", "GpioEncoderBackend", "Pin", "gpio_backend"]

log = logging.getLogger(__name__)

MAX_EDGE_GAP_S = 0.1
"""An edge this long or longer after the one before it starts a movement: the wait is not
counted into the speed (a wheel standing still, then turning, would otherwise read slow for a
period). At one edge per 0.1 s the Mini-WHEGS wheel turns 0.015 rad/s: slower is standing."""


class _Wheel:
    """One encoder's two lines and the states they went through since the last read."""

    def __init__(self, *, factory: Any, a_pin: str, b_pin: str, pull: str,
                 max_pending: int) -> None:
        self.a = factory.pin(a_pin)
        try:
            self.b = factory.pin(b_pin)
        except Exception:
            self.a.close()
            raise
        self.factory = factory
        self._lock = threading.Lock()
        self._states: deque[int] = deque(maxlen=max_pending)
        self._ticks: deque[Any] = deque(maxlen=max_pending)
        self.overflowed = 0
        self._overflowed_taken = 0  # ``overflowed`` at the last take
        self.edges_seen = 0
        self.newest_tick: Any = None
        """The stamp of the newest edge taken so far (in an earlier batch)."""
        self.moving = False
        """Whether the last batch taken had edges."""
        for pin in (self.a, self.b):
            pin.input_with_pull(pull)
            pin.edges = "both"
        self._a = int(bool(self.a.state))
        self._b = int(bool(self.b.state))
        # The state changes the callback reports are the truth; the levels read here are only
        # the starting point.
        self.a.when_changed = self._on_a
        self.b.when_changed = self._on_b

    def state(self) -> int:
        with self._lock:
            return (self._a << 1) | self._b

    def _on_a(self, ticks: Any, state: Any) -> None:
        self._record(ticks, a=int(bool(state)))

    def _on_b(self, ticks: Any, state: Any) -> None:
        self._record(ticks, b=int(bool(state)))

    def _record(self, ticks: Any, *, a: int | None = None, b: int | None = None) -> None:
        with self._lock:
            if a is not None:
                self._a = a
            if b is not None:
                self._b = b
            if len(self._states) == self._states.maxlen:
                self.overflowed += 1
            self._states.append((self._a << 1) | self._b)
            self._ticks.append(ticks)
            self.edges_seen += 1

    def take(self) -> tuple[np.ndarray, EdgeTiming]:
        """The states since the last take, and how long their edges took."""
        with self._lock:
            states = np.fromiter(self._states, dtype=np.uint8, count=len(self._states))
            ticks = list(self._ticks)
            dropped = self.overflowed - self._overflowed_taken  # from this batch
            self._overflowed_taken = self.overflowed
            self._states.clear()
            self._ticks.clear()
        timing = self._timing(ticks, dropped=dropped)
        if ticks:
            self.newest_tick = ticks[-1]
        self.moving = bool(ticks)
        return states, timing

    def _timing(self, ticks: list[Any], *, dropped: int) -> EdgeTiming:
        edges = len(ticks)
        if ticks and not dropped:  # else nothing to time, or edges missing from the count
            diff = self.factory.ticks_diff
            # ``moving``: the last batch had edges, so ``newest_tick`` is the one before these.
            if self.moving and diff(ticks[0], self.newest_tick) < MAX_EDGE_GAP_S:
                return EdgeTiming(edges=edges, span_s=diff(ticks[-1], self.newest_tick),
                                  intervals=edges)
            if edges >= 2:  # the wheel started within this batch: time it from its first edge
                return EdgeTiming(edges=edges, span_s=diff(ticks[-1], ticks[0]),
                                  intervals=edges - 1)
        return EdgeTiming(edges=edges, span_s=None, intervals=0)

    def close(self) -> None:
        for pin in (self.a, self.b):
            pin.when_changed = None
            pin.close()


class GpioEncoderBackend(EncoderBackend):
    """Both wheel encoders on GPIO; see the module docstring."""

    def __init__(self, *, factory: Any, left_a: str, left_b: str, right_a: str, right_b: str,
                 pull: Literal["up", "down", "floating"] = "up",
                 max_pending: int = 65536) -> None:
        pins = [left_a, left_b, right_a, right_b]
        if len(set(pins)) != 4:
            raise ValueError(f"the four encoder lines need four pins, got {pins}")
        if max_pending < 16:
            raise ValueError(f"max_pending must be at least 16, got {max_pending}")
        self.factory = factory
        self.left = _Wheel(factory=factory, a_pin=left_a, b_pin=left_b, pull=pull,
                           max_pending=max_pending)
        try:
            self.right = _Wheel(factory=factory, a_pin=right_a, b_pin=right_b, pull=pull,
                                max_pending=max_pending)
        except Exception:
            self.left.close()
            raise
        self.edge_timing: tuple[EdgeTiming, EdgeTiming] = (
            EdgeTiming(edges=0, span_s=None, intervals=0),) * 2
        """How long each wheel's edges of the last :meth:`read_phases` batch took."""
        self._closed = False

    def current_states(self) -> tuple[int, int]:
        """The lines' present levels, the decoders' starting point."""
        return self.left.state(), self.right.state()

    def read_phases(self) -> tuple[np.ndarray, np.ndarray]:
        (left, left_timing), (right, right_timing) = self.left.take(), self.right.take()
        self.edge_timing = (left_timing, right_timing)
        return left, right

    @property
    def last_edge_ticks(self) -> tuple[Any, Any]:
        """The pin factory's stamp of each wheel's newest edge read (``None``: none yet)."""
        return self.left.newest_tick, self.right.newest_tick

    @property
    def overflowed(self) -> int:
        """Edges dropped because a buffer filled between two reads."""
        return self.left.overflowed + self.right.overflowed

    def close(self) -> None:
        """Stop listening and release the four pins; calling it again does nothing."""
        if self._closed:
            return
        self._closed = True
        self.left.close()
        self.right.close()


def gpio_backend(
    *,
    context: DeviceContext,
    left_a: Pin,
    left_b: Pin,
    right_a: Pin,
    right_b: Pin,
    pull: Literal["up", "down", "floating"] = "up",
    pin_factory: PinFactoryName | None = None,
) -> GpioEncoderBackend:
    """``encoders.gpio``: the A/B lines of the left and right encoders on GPIO pins
    (gpiozero names, e.g. ``GPIO5``), with ``pull`` resistors (``up`` for open-collector
    encoders); ``pin_factory`` as for ``motors.gpio``. The A/B order must make a wheel
    driving the robot forward step ``0 → 1 → 3 → 2`` (B leads A); swap A and B otherwise."""
    return hardware.on_pins("encoders.gpio", pin_factory, lambda factory: GpioEncoderBackend(
        factory=factory, left_a=left_a, left_b=left_b, right_a=right_a, right_b=right_b,
        pull=pull))


gpio_backend.requires_simulator = None  # type: ignore[attr-defined]
