"""Annotated parameter types for behaviours and predicates built from robot files.

A factory's keyword annotations become its robot-file parameter schema
(:func:`ubf_async.assembly.registry.parameters_of`), so a constraint written here is checked when
the robot file is loaded. Code that builds a behaviour directly bypasses msgspec; :func:`check`
repeats the same bounds at construction, so both paths refuse the same values.
"""

from __future__ import annotations

import math
from typing import Annotated

import msgspec

from ubf_async.core.action import COMMAND_LIMIT
from ubf_async.errors import ConfigurationError

__all__ = ["Command", "LedMask", "Millimetres", "Pixels", "VoteWeight", "check"]

Command = Annotated[float, msgspec.Meta(ge=-COMMAND_LIMIT, le=COMMAND_LIMIT)]
"""A speed or turn, −100…+100 (percent of full scale)."""
Pixels = Annotated[int, msgspec.Meta(ge=0)]
LedMask = Annotated[int, msgspec.Meta(ge=0, le=255)]
"""A bit mask of LEDs to light (bit ``i`` = LED ``i``)."""
"""A count of image pixels (≥ 0)."""
Millimetres = Annotated[int, msgspec.Meta(gt=0)]
"""A distance in millimetres (> 0)."""
VoteWeight = Annotated[float, msgspec.Meta(ge=0)]
"""An action's vote (≥ 0; 0 means "no opinion")."""


def check(
    owner: str,
    name: str,
    value: float,
    *,
    ge: float | None = None,
    gt: float | None = None,
    le: float | None = None,
    integer: bool = False,
) -> None:
    """Raise :class:`~ubf_async.errors.ConfigurationError` unless ``value`` is a finite
    number (an int when ``integer``) within the bounds; the message reads
    ``"Chase: min_pixels must be ≥ 0, got -1"``."""
    kind = int if integer else (int, float)
    if isinstance(value, bool) or not isinstance(value, kind) or not math.isfinite(value):
        what = "an int" if integer else "a finite number"
        raise ConfigurationError(f"{owner}: {name} must be {what}, got {value!r}")
    for bound, ok, sign in ((ge, lambda b: value >= b, "≥"), (gt, lambda b: value > b, ">"),
                            (le, lambda b: value <= b, "≤")):
        if bound is not None and not ok(bound):
            raise ConfigurationError(f"{owner}: {name} must be {sign} {bound:g}, got {value!r}")
