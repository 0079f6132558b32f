"""What a behaviour wants done: the UBF *action*.

Every field but ``vote`` may be left unset (``None``), which is different from zero: an unset
``speed`` means "no opinion on speed", so field-wise arbiters can fill it from another
behaviour, while ``speed=0`` is a request to stand still.
"""

from __future__ import annotations

import math
from collections import namedtuple
from typing import Any, NamedTuple

__all__ = ["COMMAND_LIMIT", "FIELDS", "MAX_MESSAGE_CHARS", "NUMERIC_FIELDS", "STOP", "Action",
           "ColorBox", "clamp_command"]

COMMAND_LIMIT = 100.0
"""Speed and turn are percentages of full scale, −100…+100 (+speed forward, +turn left)."""
MAX_MESSAGE_CHARS = 256
FIELDS: tuple[str, ...] = ("speed", "turn", "seek_color", "message", "leds")
"""The action fields arbiters combine (``vote`` is the action's weight, not a field)."""
NUMERIC_FIELDS: tuple[str, ...] = ("speed", "turn")


class ColorBox(NamedTuple):
    """An inclusive RGB box the camera's seekcolor should look for."""

    lo: tuple[int, int, int]
    hi: tuple[int, int, int]


def _check_rgb(name: str, rgb: Any) -> None:
    if (
        not isinstance(rgb, tuple)
        or len(rgb) != 3
        or any(isinstance(c, bool) or not isinstance(c, int) or not 0 <= c <= 255 for c in rgb)
    ):
        raise ValueError(f"seek_color.{name} must be a tuple of three ints in 0..255, got {rgb!r}")


def _check_extras(
    seek_color: Any, message: str | None, leds: int | None
) -> ColorBox | None:
    if seek_color is not None:
        if not isinstance(seek_color, tuple) or len(seek_color) != 2:
            raise ValueError(f"Action.seek_color must be (lo, hi), got {seek_color!r}")
        lo, hi = seek_color
        _check_rgb("lo", lo)
        _check_rgb("hi", hi)
        if any(a > b for a, b in zip(lo, hi, strict=True)):
            raise ValueError(f"Action.seek_color lo {lo} exceeds hi {hi}")
        seek_color = ColorBox(lo, hi)
    if message is not None and (not isinstance(message, str) or len(message) > MAX_MESSAGE_CHARS):
        raise ValueError(f"Action.message must be a str of at most {MAX_MESSAGE_CHARS} chars")
    if leds is not None and (
        isinstance(leds, bool) or not isinstance(leds, int) or not 0 <= leds <= 255
    ):
        raise ValueError(f"Action.leds must be a bit mask 0..255, got {leds!r}")
    return seek_color


def clamp_command(value: float) -> float:
    """Clamp a finite speed/turn to ±100; NaN and infinities are refused."""
    if not math.isfinite(value):
        raise ValueError(f"command value must be finite, got {value!r}")
    return max(-COMMAND_LIMIT, min(COMMAND_LIMIT, value))


_INF = math.inf
_ActionFields = namedtuple(
    "_ActionFields", ("speed", "turn", "vote", "seek_color", "message", "leds")
)


class Action(_ActionFields):
    """A behaviour's request plus its vote (activation). Immutable.

    ``vote`` is how strongly the behaviour wants this action (finite, ≥ 0). A vote of 0 means
    "no opinion": every arbiter treats it exactly like returning ``None``. The default vote is
    1 so that a behaviour that does not care about activation still counts.

    Construction validates: speed/turn must be finite and within ±100 (use
    :func:`clamp_command` first if you compute them), LEDs a bit mask 0..255, the message at
    most 256 characters. Invalid values raise :class:`ValueError` — an action that exists is
    always safe to hand to the hardware layer.

    (A tuple underneath, because an action is made on every tick by every behaviour and this
    is the cheapest immutable record Python offers; compare actions with ``==`` as usual.)
    """

    __slots__ = ()

    def __new__(
        cls,
        *,
        speed: float | None = None,
        turn: float | None = None,
        vote: float = 1.0,
        seek_color: ColorBox | tuple[tuple[int, int, int], tuple[int, int, int]] | None = None,
        message: str | None = None,
        leds: int | None = None,
    ) -> Action:
        # Chained comparisons are False for NaN and reject ±inf: one test covers range and
        # finiteness; non-numbers raise TypeError, turned into ValueError below.
        try:
            if speed is not None and (speed.__class__ is bool or not -100.0 <= speed <= 100.0):
                raise ValueError(f"Action.speed must be finite and within ±100, got {speed!r}")
            if turn is not None and (turn.__class__ is bool or not -100.0 <= turn <= 100.0):
                raise ValueError(f"Action.turn must be finite and within ±100, got {turn!r}")
            if vote.__class__ is bool or not 0.0 <= vote < _INF:
                raise ValueError(f"Action.vote must be a finite number ≥ 0, got {vote!r}")
        except TypeError:
            raise ValueError(
                f"Action speed/turn/vote must be numbers, got {speed!r}, {turn!r}, {vote!r}"
            ) from None
        if seek_color is not None or message is not None or leds is not None:
            seek_color = _check_extras(seek_color, message, leds)
        return tuple.__new__(cls, (speed, turn, vote, seek_color, message, leds))

    def __repr__(self) -> str:
        return f"Action({self.describe()})"

    @property
    def abstains(self) -> bool:
        """True when the vote is 0: the action carries no opinion."""
        return self.vote == 0

    def is_set(self, field: str) -> bool:
        return getattr(self, field) is not None

    def replace(self, **changes: Any) -> Action:
        """A copy with ``changes`` applied (validated like a new action)."""
        return Action(**{**self._asdict(), **changes})

    def describe(self) -> str:
        """Compact text of the set fields, e.g. ``speed=+40 turn=+30 vote=1``."""
        parts = []
        for name in FIELDS:
            value = getattr(self, name)
            if value is None:
                continue
            if name in NUMERIC_FIELDS:
                parts.append(f"{name}={value:+.0f}")
            elif name == "seek_color":
                parts.append(f"seek_color={list(value.lo)}..{list(value.hi)}")
            else:
                parts.append(f"{name}={value!r}")
        parts.append(f"vote={self.vote:g}")
        return " ".join(parts)


STOP = Action(speed=0.0, turn=0.0)
"""Stand still."""
