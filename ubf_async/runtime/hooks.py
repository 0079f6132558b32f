"""Observers: callbacks a component calls at a moment of its own (the aggregator on each sample,
the controller on each tick), added and removed by those who watch — one mechanism for both."""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import ParamSpec

__all__ = ["add_hook", "run_hooks"]

log = logging.getLogger(__name__)

P = ParamSpec("P")


def add_hook(hooks: list[Callable[P, None]], callback: Callable[P, None]) -> Callable[[], None]:
    """Append ``callback`` to ``hooks``; returns a remover (idempotent)."""
    hooks.append(callback)

    def remove() -> None:
        if callback in hooks:
            hooks.remove(callback)

    return remove


def run_hooks(hooks: list[Callable[P, None]], what: str, *args: P.args, **kwargs: P.kwargs
              ) -> None:
    """Call each of ``hooks`` in the order they were added. One that raises is logged and
    removed (it is an observer: its failure must not stop what it observes). Callers check
    ``if hooks:`` first, so no hook costs one truth test."""
    for hook in tuple(hooks):
        try:
            hook(*args, **kwargs)
        except Exception:
            log.exception("%s hook %r raised: removed", what, hook)
            if hook in hooks:
                hooks.remove(hook)
