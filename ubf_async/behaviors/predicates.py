"""Predicates for :class:`~ubf_async.core.arbiters.Conditional`, registered by name.

Each entry of the ``ubf_async.predicates`` entry-point group is a *factory*: called with its
keyword parameters (from a robot file's ``predicate_params``, checked against the signature
by :func:`~ubf_async.assembly.registry.parameters_of`) it returns the predicate ``State -> bool``
that the Conditional asks every tick. A predicate must not block; it runs on the event loop.

* ``sees_color(source="camera/front", min_pixels=1)`` — a fresh camera seekcolor reading
  whose bins add up to at least ``min_pixels``;
* ``obstacle_within(near_mm=250, sources=())`` — a fresh range reading within ``near_mm``
  (or ``too_close``) on one of ``sources`` (default: every ``range/*`` source), as the
  ``avoid`` behaviour reacts to;
* ``source_fresh(source)`` — ``source`` has a reading that is not stale.

Missing and stale readings make every predicate false.
"""

from __future__ import annotations

from collections.abc import Sequence

from ubf_async.behaviors.obstacles import DEFAULT_NEAR_MM, nearest_obstacle
from ubf_async.behaviors.params import Millimetres, Pixels, check
from ubf_async.core.arbiters import Predicate
from ubf_async.core.state import State
from ubf_async.errors import ConfigurationError
from ubf_async.wire.topics import require_field

__all__ = ["CAMERA_SOURCE", "obstacle_within", "sees_color", "source_fresh"]

CAMERA_SOURCE = "camera/front"


def sees_color(*, source: str = CAMERA_SOURCE, min_pixels: Pixels = 1) -> Predicate:
    """True when ``source``'s fresh seekcolor reading has at least ``min_pixels`` pixels of
    the colour in its ``bins`` (so ``min_pixels=0`` means "the camera is reporting")."""
    check("sees_color", "min_pixels", min_pixels, ge=0, integer=True)
    require_field(source, "bins", who="sees_color")

    def predicate(state: State) -> bool:
        bins = state.value(source, "bins")
        return bins is not None and sum(bins) >= min_pixels

    predicate.__name__ = f"sees_color({source}, ≥{min_pixels}px)"
    return predicate


def obstacle_within(
    *, near_mm: Millimetres = DEFAULT_NEAR_MM, sources: Sequence[str] = ()
) -> Predicate:
    """True when a fresh range reading of ``sources`` (every ``range/*`` source when empty)
    is within ``near_mm``, or reports ``too_close``."""
    check("obstacle_within", "near_mm", near_mm, gt=0, integer=True)
    watched = tuple(sources)
    for source in watched:
        require_field(source, "range_mm", who="obstacle_within")

    def predicate(state: State) -> bool:
        return nearest_obstacle(state, near_mm, watched) is not None

    predicate.__name__ = f"obstacle_within({near_mm}mm)"
    return predicate


def source_fresh(*, source: str) -> Predicate:
    """True when ``source`` has a reading that is not stale."""
    if not source:
        raise ConfigurationError("source_fresh: source must not be empty")

    def predicate(state: State) -> bool:
        return state.fresh(source) is not None

    predicate.__name__ = f"source_fresh({source})"
    return predicate
