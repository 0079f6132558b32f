"""Building a device from the registry: a device kind, a backend, parameters checked by type.

The device kinds (entry points ``ubf_async.devices``) and their backends
(``ubf_async.backends``, ``<kind>.<backend>``) are looked up by name, exactly as launch does
for a robot file; their keyword parameters are checked with
:func:`ubf_async.assembly.registry.parameters_of` before anything is built. A device started on its
own (:mod:`components.standalone`) and the simulator's in-process helper
(:func:`components.sim.component.simulated_devices`) both build through :func:`make_device`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import msgspec

from ubf_async.assembly import registry
from ubf_async.assembly.context import DeviceContext
from ubf_async.assembly.devices import (
    BACKEND_INJECTED,
    DEVICE_INJECTED,
    build_device,
    requires_simulator,
    typed_params,
)
from ubf_async.errors import ConfigurationError
from ubf_async.runtime.component import Component

__all__ = ["BACKEND_INJECTED", "DEFAULT_NAMES", "DEVICE_INJECTED", "KINDS", "checked",
           "make_backend", "make_device", "requires_simulator"]

KINDS = ("motors", "encoders", "camera", "range", "radio", "leds")
"""The built-in device kinds."""
DEFAULT_NAMES: dict[str, str] = {"camera": "front", "motors": "main", "encoders": "wheels",
                                 "range": "front", "radio": "link", "leds": "panel"}
"""Each built-in kind's usual source name (``sensor/<kind>/<name>``)."""


def checked(factory: Callable[..., Any], params: Mapping[str, Any], *,
            injected: frozenset[str], what: str) -> dict[str, Any]:
    """``params`` checked against ``factory``'s keyword parameters (defaults filled in).

    Raises :class:`~ubf_async.errors.ConfigurationError` naming ``what`` and the field.
    """
    try:
        return typed_params(factory, params, injected=injected)
    except msgspec.ValidationError as exc:
        raise ConfigurationError(f"{what}: {exc}") from None


def make_backend(kind: str, backend: str, *, context: DeviceContext,
                 params: Mapping[str, Any] | None = None) -> Any:
    """The backend ``backend`` of device ``kind``, built with ``params`` in ``context``."""
    factory = registry.get_backend(kind, backend)
    values = checked(factory, params or {}, injected=BACKEND_INJECTED,
                     what=f"backend {kind}.{backend}")
    return factory(context=context, **values)


def make_device(
    kind: str,
    *,
    context: DeviceContext,
    backend: Any,
    name: str | None = None,
    params: Mapping[str, Any] | None = None,
) -> Component:
    """A device component of ``kind`` on ``context.bus``, reading/driving ``backend`` (an
    object built by :func:`make_backend`, or any object following the kind's backend
    interface). ``name`` defaults to the kind's usual one; ``params`` are checked against the
    kind's factory; the run's seed and clock are given to a factory that takes them."""
    factory = registry.DEVICES.get(kind)
    name = name if name is not None else DEFAULT_NAMES.get(kind, kind)
    values = checked(factory, params or {}, injected=DEVICE_INJECTED, what=f"{kind} {name!r}")
    return build_device(factory, kind=kind, name=name, backend=backend, params=values,
                        context=context)
