"""Plug-ins by name where the core takes objects: a predicate by its registered name for the
``Conditional`` arbiter.

The core (:mod:`ubf_async.core.arbiters`) takes a predicate as a callable and knows no
registry; a robot file names one (``predicate: sees_color``, ``predicate_params: {…}``), and
:func:`conditional` — the ``Conditional`` entry point's target — resolves the name here.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from ubf_async.assembly import registry
from ubf_async.core.arbiters import Conditional, Predicate
from ubf_async.errors import ConfigurationError, PluginError

__all__ = ["conditional", "predicate_from"]


def predicate_from(reference: str, params: Mapping[str, Any] | None = None) -> Predicate:
    """The predicate a robot file names: ``reference`` is a name registered in the
    ``ubf_async.predicates`` group (``sees_color``) or a ``module:factory`` reference, and
    ``params`` the keyword parameters of that *factory*, which returns ``State -> bool``.

    ``params`` are checked against the factory's signature
    (:func:`~ubf_async.assembly.registry.checked_params`) before it is called. Raises
    :class:`~ubf_async.errors.PluginError` for an unknown or unusable factory and
    :class:`~ubf_async.errors.ParameterError` (a ``ConfigurationError``) for parameters it
    refuses.
    """
    factory = registry.PREDICATES.get(reference)
    if not callable(factory):
        raise PluginError(f"predicate {reference!r} is a {type(factory).__name__}, not a "
                          f"factory returning State -> bool")
    kwargs = registry.checked_params(factory, params or {}, what=f"predicate {reference!r}")
    try:
        predicate = factory(**kwargs)
    except (TypeError, ValueError) as exc:  # ConfigurationError is a ValueError
        raise ConfigurationError(f"predicate {reference!r}: {exc}") from exc
    if not callable(predicate):
        raise PluginError(f"predicate factory {reference!r} returned a "
                          f"{type(predicate).__name__}, not a State -> bool callable")
    return predicate


def conditional(
    *,
    predicate: str,
    predicate_params: dict[str, Any] | None = None,
    label: str | None = None,
) -> Conditional:
    """:class:`Conditional` from plain data — the ``Conditional`` entry point's target.

    The class takes a Python callable, which no robot file can give; this factory takes the
    predicate's name and parameters — plain data :func:`~ubf_async.assembly.registry.parameters_of`
    can check — and labels the arbiter with them (``sees_color(min_pixels=1)``).
    """
    if not isinstance(predicate, str):
        raise ConfigurationError(
            f"Conditional: predicate must be a registered name or a 'module:factory' "
            f"reference, got {type(predicate).__name__}")
    shown = ", ".join(f"{k}={v!r}" for k, v in (predicate_params or {}).items())
    return Conditional(predicate_from(predicate, predicate_params),
                       label=label or (f"{predicate}({shown})" if shown else predicate))
