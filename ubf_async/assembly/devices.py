"""Building a device from its plug-ins: a device kind and a backend, found by name.

A device kind (entry point ``ubf_async.devices``) is a factory ``(*, bus, name, backend,
**params)`` returning a :class:`~ubf_async.runtime.component.Component`; a backend
(``ubf_async.backends``, named ``KIND.NAME``) is a factory ``(*, context, **params)``. Their
other keyword parameters are checked with :func:`~ubf_async.assembly.registry.checked_params`,
the device and its backend named alike (:func:`device_label`, :func:`backend_label`). Launch
(through a robot file) and a device started on its own both build through here.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

from ubf_async.assembly.backend import Backend
from ubf_async.assembly.context import DeviceContext
from ubf_async.assembly.registry import accepts
from ubf_async.errors import ConfigurationError
from ubf_async.runtime.component import Component
from ubf_async.wire.topics import Topic

__all__ = ["BACKEND_INJECTED", "DEVICE_INJECTED", "backend_label", "build_device",
           "checked_backend", "device_label", "further_topics", "requires_simulator"]

DEVICE_INJECTED = frozenset({"bus", "name", "backend", "seed", "clock", "body"})
"""Parameters of a device kind's factory the builder supplies itself."""
BACKEND_INJECTED = frozenset({"context"})
"""Parameters of a backend factory the builder supplies itself."""


def requires_simulator(factory: Callable[..., Any]) -> str | None:
    """The simulator plug-in a backend factory needs (its ``requires_simulator``), or None."""
    name = getattr(factory, "requires_simulator", None)
    if name is not None and not isinstance(name, str):
        raise ConfigurationError(f"{factory!r}: requires_simulator must be a str or None, "
                                 f"got {name!r}")
    return name


def further_topics(factory: Callable[..., Any]) -> tuple[Topic[Any], ...]:
    """The topics a device kind's component publishes for its own name besides
    ``sensor/<kind>/<name>`` (its factory's ``publishes_also``: the camera's view, the
    encoders' odometry), which a secure set-up grants the device's own identity. Each has the
    one placeholder ``{name}``."""
    topics = tuple(getattr(factory, "publishes_also", ()))
    for topic in topics:
        if not isinstance(topic, Topic) or topic.placeholders != ("name",):
            raise ConfigurationError(f"{factory!r}: publishes_also must hold topics of "
                                     f"ubf_async.wire.topics keyed by {{name}} alone, got "
                                     f"{topic!r}")
    return topics


def checked_backend(backend: object, *, what: str) -> Backend:
    """``backend``, refused (a :class:`~ubf_async.errors.ConfigurationError` naming ``what``)
    unless it is a :class:`~ubf_async.assembly.backend.Backend` — when it is built, not when
    it is to be closed."""
    if not isinstance(backend, Backend):
        raise ConfigurationError(
            f"{what}: its backend is a {type(backend).__name__}, not a "
            f"ubf_async.assembly.backend.Backend: derive the backend's class from the kind's "
            f"backend interface or from Backend (docs/your-device.md)")
    return backend


def device_label(kind: str, name: str) -> str:
    """How a refusal names a device (``range 'front'``), wherever it is built."""
    return f"{kind} {name!r}"


def backend_label(kind: str, backend: str) -> str:
    """How a refusal names a device's backend (``backend encoders.sim``)."""
    return f"backend {kind}.{backend}"


def build_device(factory: Callable[..., Any], *, kind: str, name: str, backend: Any,
                 params: Mapping[str, Any], context: DeviceContext) -> Component:
    """The component of device kind ``kind`` (its factory ``factory``) reading or driving
    ``backend``, with already checked ``params``; the run's seed and clock go to a factory
    that takes them, and so does each of ``context.extras`` the robot file does not set (a
    fleet's world gives the encoders their robot's start pose, ``origin_x_m`` …), and so does
    the robot's body (``context.body``) to a factory that takes ``body``. The device
    owns ``backend`` (a :class:`~ubf_async.assembly.backend.Backend`): its ``aclose()`` is
    awaited when the component closes, or at once if no component is made."""
    backend = checked_backend(backend, what=device_label(kind, name))
    # What the run knows fills the parameters the robot file left unset (None).
    extra: dict[str, Any] = {
        key: value for key, value in context.extras.items()
        if params.get(key) is None and accepts(factory, key)}
    params = {key: value for key, value in params.items() if key not in extra}
    if accepts(factory, "seed"):
        extra["seed"] = context.seed
    if accepts(factory, "clock"):
        extra["clock"] = context.clock
    if accepts(factory, "body"):
        extra["body"] = context.body
    try:
        component = factory(bus=context.bus, name=name, backend=backend, **extra, **params)
        if not isinstance(component, Component):
            raise ConfigurationError(f"device kind {kind!r} returned "
                                     f"{type(component).__name__}, not a Component")
    except BaseException:
        backend.close()  # refused: its pins and buses are not left held (no loop to await on)
        raise
    # The device owns its backend: closed with it, after its last command.
    component.close_on_exit(backend.aclose)
    return component
