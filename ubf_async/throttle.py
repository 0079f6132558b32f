"""One rule for repeated log lines: a count of something going wrong is logged the first time
and every ``every``-th time after, so a flood of bad input says so without flooding the log."""

from __future__ import annotations

__all__ = ["first_and_every", "passes"]


def first_and_every(count: int, every: int = 100) -> bool:
    """Whether the ``count``-th occurrence (1 for the first) should be logged."""
    return count == 1 or count % every == 0


def passes(before: int, after: int, every: int = 100) -> bool:
    """Whether a count that jumped from ``before`` to ``after`` (several counted at once)
    passed an occurrence :func:`first_and_every` logs."""
    return after > before and (before == 0 or after // every > before // every)
