"""Building a device from the registry: a device kind, a backend, parameters checked by type.

The device kinds (entry points ``ubf_async.devices``) and their backends
(``ubf_async.backends``, ``<kind>.<backend>``) are looked up by name, exactly as launch does
for a robot file; their keyword parameters are checked before anything is built, by the check a
robot file's go through (:func:`ubf_async.assembly.registry.checked_params`): the same mistake,
the same :class:`~ubf_async.errors.ParameterError`. A device started on its own
(:mod:`components.standalone`) and the simulator's in-process helper
(:func:`components.sim.runner.stepper.simulated_devices`) both build through :func:`make_device`.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from ubf_async.assembly import registry
from ubf_async.assembly.backend import Backend
from ubf_async.assembly.context import DeviceContext
from ubf_async.assembly.devices import (
    BACKEND_INJECTED,
    DEVICE_INJECTED,
    backend_label,
    build_device,
    checked_backend,
    device_label,
    requires_simulator,
)
from ubf_async.runtime.component import Component

__all__ = ["BACKEND_INJECTED", "DEFAULT_NAMES", "DEVICE_INJECTED", "KINDS", "make_backend",
           "make_device", "requires_simulator"]

KINDS = ("motors", "encoders", "camera", "range", "radio", "leds")
"""The built-in device kinds."""
DEFAULT_NAMES: dict[str, str] = {"camera": "front", "motors": "main", "encoders": "wheels",
                                 "range": "front", "radio": "link", "leds": "panel"}
"""Each built-in kind's usual source name (``sensor/<kind>/<name>``)."""


def make_backend(kind: str, backend: str, *, context: DeviceContext,
                 params: Mapping[str, Any] | None = None) -> Backend:
    """The backend ``backend`` of device ``kind``, built with ``params`` in ``context``."""
    factory = registry.get_backend(kind, backend)
    what = backend_label(kind, backend)
    values = registry.checked_params(factory, params or {}, injected=BACKEND_INJECTED,
                                     what=what)
    return checked_backend(factory(context=context, **values), what=what)


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
    values = registry.checked_params(factory, params or {}, injected=DEVICE_INJECTED,
                                     what=device_label(kind, name))
    return build_device(factory, kind=kind, name=name, backend=backend, params=values,
                        context=context)
