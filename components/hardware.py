"""What the real-hardware backends share: the optional libraries and the GPIO pin factory.

The hardware libraries (gpiozero, smbus2) are the ``hardware`` extra
(``pip install 'ubf-async[hardware]'``): only the backends that drive real pins or buses import
them, through :func:`require`, so a robot without them still installs and runs.

GPIO goes through gpiozero's pin factories, chosen as gpiozero chooses them: the
``pin_factory`` parameter of a backend names one (``lgpio``, ``rpigpio``, ``pigpio``,
``native``, ``mock``); left unset, gpiozero's default applies (the ``GPIOZERO_PIN_FACTORY``
environment variable, else the first that loads). All the backends of one process share one
factory per name, so a test driving the ``mock`` factory's pins reaches the pins the backends
use. ``mock`` takes its pin class from ``GPIOZERO_MOCK_PIN_CLASS`` (``mockpwmpin`` for PWM
outputs), as gpiozero does.
"""

from __future__ import annotations

import logging
import sys
import threading
import warnings
from collections.abc import Callable
from types import ModuleType
from typing import Annotated, Any, TypeVar

import msgspec

from ubf_async import extras
from ubf_async.errors import ConfigurationError

__all__ = ["Pin", "PinFactoryName", "describe", "gpio_errors", "on_pins", "pin_factory",
           "pins_error", "require"]

log = logging.getLogger(__name__)

T = TypeVar("T")

Pin = Annotated[str, msgspec.Meta(min_length=1, max_length=32)]
"""A pin as gpiozero names it, in a GPIO backend's parameters: ``"GPIO12"``, ``"12"``,
``"BOARD32"``."""
PinFactoryName = Annotated[str, msgspec.Meta(max_length=32)]
"""A GPIO backend's ``pin_factory`` parameter: a factory's name (:func:`pin_factory`)."""

_FACTORIES: dict[str, Any] = {}
_LOCK = threading.Lock()


def require(module: str, *, who: str) -> ModuleType:
    """Import ``module`` for backend ``who``, or say how to install it
    (:func:`ubf_async.extras.require`)."""
    return extras.require("hardware", module, who=who)


def gpio_errors() -> tuple[type[BaseException], ...]:
    """gpiozero's exception root (gpiozero is installed once a pin factory was had)."""
    from gpiozero.exc import GPIOZeroError

    return (GPIOZeroError,)


def describe(exc: BaseException) -> str:
    """An exception as ``TypeName: message``: several of gpiozero's carry no message at all
    (``PinPWMUnsupported()``), and its type is then all that says what went wrong."""
    text = str(exc).strip()
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def pins_error(who: str, exc: BaseException) -> ConfigurationError:
    """A one-line error for pins that cannot be had (taken, wrong name, no permission, no PWM),
    with a hint at the likely cause."""
    gpio_exc = sys.modules.get("gpiozero.exc")  # loaded if gpiozero raised it
    if gpio_exc is not None and isinstance(exc, gpio_exc.PinPWMUnsupported):
        hint = ("this pin factory cannot do PWM on these pins: use lgpio or pigpio (docs/"
                "hardware.md); gpiozero's mock factory needs GPIOZERO_MOCK_PIN_CLASS="
                "mockpwmpin")
    else:
        hint = ("pin names as gpiozero knows them, e.g. GPIO12; are you in the gpio group? "
                "docs/hardware.md")
    return ConfigurationError(f"{who}: cannot set up the pins: {describe(exc)} ({hint})")


def on_pins(who: str, factory_name: str | None, build: Callable[[Any], T]) -> T:
    """``build(factory)`` on the pin factory ``factory_name`` (:func:`pin_factory`): what a
    GPIO backend's factory does, pins it cannot have (taken, misnamed, not allowed) refused
    in one line (:func:`pins_error`)."""
    factory = pin_factory(factory_name, who=who)
    refused: tuple[type[BaseException], ...] = (OSError, ValueError, *gpio_errors())
    try:
        return build(factory)
    except refused as exc:
        raise pins_error(who, exc) from None


def pin_factory(name: str | None, *, who: str) -> Any:
    """The gpiozero pin factory ``name`` (``None``: gpiozero's default), one per process."""
    devices = require("gpiozero.devices", who=who)
    with _LOCK:
        key = name or ""
        factory = _FACTORIES.get(key)
        if factory is not None:
            return factory
        # gpiozero warns once per factory it falls back from (four lines off a Pi before
        # its error): they are folded into the one line said here instead.
        with warnings.catch_warnings(record=True) as fallbacks:
            warnings.simplefilter("always")
            try:
                if name is None:
                    factory = (devices.Device.pin_factory
                               or devices.Device._default_pin_factory())
                    devices.Device.pin_factory = factory
                else:
                    factory = _load_factory(name)
            except Exception as exc:  # gpiozero's BadPinFactory, or the library's own error
                tried = "; ".join(str(w.message).removeprefix("Falling back from ")
                                  for w in fallbacks)
                venv = ("; in a venv, apt's python3-lgpio needs --system-site-packages, or "
                        "pip install lgpio" if "No module named 'lgpio'" in tried else "")
                raise ConfigurationError(
                    f"{who}: no GPIO pin factory {name or '(default)'!r}: {describe(exc)}"
                    + (f" (tried {tried})" if tried else "") + f" (docs/hardware.md, Pin "
                    f"factories{venv})") from None
        for fallback in fallbacks:
            log.info("%s: %s", who, fallback.message)
        _FACTORIES[key] = factory
        return factory


def _load_factory(name: str) -> Any:
    from importlib.metadata import entry_points

    found = {ep.name: ep for ep in entry_points(group="gpiozero_pin_factories")}
    entry = found.get(name) or found.get(name.lower())
    if entry is None:
        raise ValueError(f"gpiozero knows {', '.join(sorted(found))}")
    return entry.load()()
