"""Plug-ins by name: behaviours, arbiters, predicates, device kinds, backends, simulators.

Every built-in is registered exactly as a third-party one is: through an *entry point* in a
package's metadata (``[project.entry-points."ubf_async.behaviors"]`` in ``pyproject.toml``).
A pip-installed package adds its own under the same groups:

====================  ========================================================  ==========
group                 what a name stands for                                    example
====================  ========================================================  ==========
ubf_async.behaviors   a factory returning a :class:`.Behavior`                  ``search``
ubf_async.arbiters    a factory returning an :class:`.Arbiter`                  ``PriorityMerge``
ubf_async.predicates  ``(**params) -> (State -> bool)``, for ``Conditional``    ``sees_color``
ubf_async.devices     a device kind: ``(*, bus, name, backend, **params)``      ``camera``
ubf_async.backends    ``KIND.NAME``: ``(*, context, **params) -> backend``      ``camera.sim``
ubf_async.simulators  a :class:`.Simulator` factory                             ``mini-whegs``
ubf_async.live_views  ``() -> LiveConverter``, for the live view and recordings ``sim.world``
====================  ========================================================  ==========

Only these groups are read. Entry points a package registers under another ``ubf_async.*``
group (``ubf_async.core.arbiters``, a module's path rather than the group's name) are found by
:func:`unread_groups`: ``python -m ubf_async.robotfile plugins`` lists them, and an unknown name
that such a group holds is refused with the group it was likely meant for.

Where a name is expected, a ``module:attribute`` reference to the user's own code works too
(``my_robot.behaviors:Wander``). An unknown name raises :class:`~ubf_async.errors.PluginError`
listing the known ones.

A factory's keyword parameters are its robot-file parameters: :func:`parameters_of` turns its
signature into a msgspec Struct, so what a robot file passes is type-checked before anything
is built, and a missing or misspelt parameter is reported at load time. :func:`checked_params`
is the one check every builder runs (a robot file, a device started on its own, a
``Conditional``'s predicate): the same refusal, :class:`~ubf_async.errors.ParameterError`,
for the same mistake.
"""

from __future__ import annotations

import difflib
import importlib
import inspect
import re
import threading
import typing
from collections.abc import Callable, Iterable, Mapping
from importlib.metadata import EntryPoint, entry_points
from typing import Any

import msgspec
import msgspec.inspect

from ubf_async import extras
from ubf_async.errors import MissingExtraError, ParameterError, PluginError

__all__ = ["ARBITERS", "BACKENDS", "BEHAVIORS", "DEVICES", "GROUP_PREFIX", "LIVE_VIEWS",
           "PREDICATES", "READ", "REFERENCE_SEPARATOR", "SIMULATORS", "Registry", "accepts",
           "backends_for", "checked_params", "get_backend", "is_reference", "meant_group",
           "parameters_of", "resolve_reference", "unread_groups", "validation_parts"]

REFERENCE_SEPARATOR = ":"
GROUP_PREFIX = "ubf_async."
"""Every entry-point group of ubf_async starts so."""


def resolve_reference(reference: str) -> Any:
    """Import ``module:attribute`` (attribute may be dotted). Raises :class:`PluginError`."""
    module_name, sep, attribute = reference.partition(REFERENCE_SEPARATOR)
    if not sep or not module_name or not attribute:
        raise PluginError(f"{reference!r} is not a 'module:attribute' reference")
    try:
        target: Any = importlib.import_module(module_name)
    except ImportError as exc:
        raise PluginError(f"cannot import {module_name!r} for {reference!r}: {exc}") from exc
    for part in attribute.split("."):
        try:
            target = getattr(target, part)
        except AttributeError:
            raise PluginError(f"{module_name!r} has no attribute {attribute!r}") from None
    return target


def is_reference(name: str) -> bool:
    return REFERENCE_SEPARATOR in name


class Registry:
    """The plug-ins of one entry-point group, plus any registered at run time.

    Entry points are read once, on first use; the objects they name are imported only when
    asked for, so a robot pays only for the plug-ins it uses (and a broken plug-in breaks only
    the robots that name it).
    """

    def __init__(self, group: str, *, what: str) -> None:
        self.group = group
        self.what = what
        READ[group] = self
        self._entry_points: dict[str, EntryPoint] | None = None
        self._loaded: dict[str, Any] = {}
        self._lock = threading.Lock()

    def _points(self) -> dict[str, EntryPoint]:
        with self._lock:
            if self._entry_points is None:
                self._entry_points = {ep.name: ep for ep in entry_points(group=self.group)}
            return self._entry_points

    def names(self) -> list[str]:
        """Every name this group knows, sorted."""
        return sorted({*self._points(), *self._loaded})

    def register(self, name: str, obj: Any) -> None:
        """Add (or replace) ``name`` at run time, e.g. from a test or an application."""
        self._loaded[name] = obj

    def unregister(self, name: str) -> None:
        self._loaded.pop(name, None)
        points = self._points()
        points.pop(name, None)

    def origin(self, name: str) -> str:
        """Where ``name`` comes from: the entry point's ``module:attr``, or the reference."""
        if is_reference(name):
            return name
        point = self._points().get(name)
        if point is not None:
            return point.value
        obj = self._loaded.get(name)
        if obj is None:
            return "?"
        return f"{getattr(obj, '__module__', '?')}:{getattr(obj, '__qualname__', '?')}"

    def get(self, name: str, *, known: Iterable[str] | None = None) -> Any:
        """The object ``name`` stands for: a registered name or a ``module:attr`` reference.

        Raises :class:`PluginError` naming the known names (``known`` narrows that list, e.g.
        to one device kind's backends).
        """
        if name in self._loaded:
            return self._loaded[name]
        if is_reference(name):
            return resolve_reference(name)
        point = self._points().get(name)
        if point is None:
            choices = list(known) if known is not None else self.names()
            raise PluginError(
                f"unknown {self.what} {name!r}; known: {', '.join(choices) or '(none)'}"
                f" (or a 'module:factory' reference){self._unread_hint(name)}"
            )
        try:
            obj = point.load()
        except MissingExtraError:
            raise  # the plug-in's own words: the extra its feature needs
        except Exception as exc:  # a plug-in's import may fail in any way
            missing = extras.missing_extra(exc, who=f"{self.what} {name!r}")
            if missing is not None:
                raise missing from None
            raise PluginError(f"{self.what} {name!r} ({point.value}) failed to load: "
                              f"{type(exc).__name__}: {exc}") from exc
        self._loaded[name] = obj
        return obj

    def _unread_hint(self, name: str) -> str:
        """What the unread groups say about an unknown ``name``: where it is registered in
        vain, and the group meant."""
        said = [f"{name!r} is registered under {group}, which nothing reads"
                for group, points in unread_groups().items()
                if any(point.name == name for point in points)]
        if not said:
            return ""
        return f"; {'; '.join(said)}: did you mean group {self.group}?"


READ: dict[str, Registry] = {}
"""Every group ubf_async reads, and its registry."""


def unread_groups() -> dict[str, list[EntryPoint]]:
    """Entry points registered under a ``ubf_async.*`` group that no registry reads, by group
    (a package following a wrong name of a group: its plug-ins would be silently left out)."""
    unread = sorted(group for group in entry_points().groups
                    if group.startswith(GROUP_PREFIX) and group not in READ)
    return {group: list(entry_points(group=group)) for group in unread}


def meant_group(group: str) -> str | None:
    """The group read that an unread ``group`` was likely meant to be: the one named by its
    last part (``ubf_async.core.arbiters`` → ``ubf_async.arbiters``), else the closest name."""
    by_last = {read.rpartition(".")[2]: read for read in READ}
    last = group.rpartition(".")[2]
    if last in by_last:
        return by_last[last]
    close = difflib.get_close_matches(last, list(by_last), n=1, cutoff=0.6)
    return by_last[close[0]] if close else None


BEHAVIORS = Registry("ubf_async.behaviors", what="behaviour")
ARBITERS = Registry("ubf_async.arbiters", what="arbiter")
PREDICATES = Registry("ubf_async.predicates", what="predicate")
DEVICES = Registry("ubf_async.devices", what="device kind")
BACKENDS = Registry("ubf_async.backends", what="backend")
SIMULATORS = Registry("ubf_async.simulators", what="simulator")
LIVE_VIEWS = Registry("ubf_async.live_views", what="live view")


def backends_for(kind: str) -> list[str]:
    """Backend names registered for device ``kind`` (``camera.sim`` → ``sim``)."""
    prefix = f"{kind}."
    return [name[len(prefix):] for name in BACKENDS.names() if name.startswith(prefix)]


def get_backend(kind: str, name: str) -> Any:
    """The backend factory ``name`` for device ``kind`` (``name`` may be a reference)."""
    if is_reference(name):
        return resolve_reference(name)
    return BACKENDS.get(f"{kind}.{name}", known=backends_for(kind))


# -- parameters from signatures ---------------------------------------------------------------

_PARAMETER_CACHE: dict[tuple[Any, frozenset[str]], type[msgspec.Struct]] = {}


def parameters_of(factory: Callable[..., Any], *, injected: Iterable[str] = ()) -> type[
        msgspec.Struct]:
    """A msgspec Struct type of the keyword parameters a robot file may give ``factory``.

    ``injected`` names parameters the builder supplies itself (``name``, ``rng``, ``bus``…);
    they are left out. A parameter without a default is required; unknown keys are refused.
    Parameters must carry annotations that msgspec understands (``float``, ``int``, ``str``,
    ``bool``, ``list[...]``, ``Literal[...]``, ``Annotated[float, msgspec.Meta(ge=0)]``…);
    one without an annotation accepts any value.
    """
    skip = frozenset(injected)
    key = (factory, skip)
    cached = _PARAMETER_CACHE.get(key)
    if cached is not None:
        return cached
    target = factory.__init__ if inspect.isclass(factory) else factory
    signature = inspect.signature(factory)
    try:
        hints = typing.get_type_hints(target, include_extras=True)
    except Exception:  # unresolvable annotations: fall back to Any for each
        hints = {}
    fields: list[tuple[str, Any] | tuple[str, Any, Any]] = []
    for parameter in signature.parameters.values():
        if parameter.name in skip or parameter.kind in (
                inspect.Parameter.VAR_POSITIONAL, inspect.Parameter.VAR_KEYWORD):
            continue
        annotation = _data_type(hints.get(parameter.name, Any))
        if parameter.default is inspect.Parameter.empty:
            fields.append((parameter.name, annotation))
        else:
            fields.append((parameter.name, annotation, parameter.default))
    # Required fields first, as a Struct needs them.
    fields.sort(key=lambda f: len(f) == 3)
    name = getattr(factory, "__qualname__", "factory").replace(".", "_") + "Parameters"
    struct = msgspec.defstruct(name, fields, kw_only=True, forbid_unknown_fields=True)
    _PARAMETER_CACHE[key] = struct
    return struct


def checked_params(factory: Callable[..., Any], params: Mapping[str, Any], *,
                   injected: Iterable[str] = (), what: str) -> dict[str, Any]:
    """``params`` checked against ``factory``'s keyword parameters (:func:`parameters_of`),
    defaults filled in.

    Raises :class:`~ubf_async.errors.ParameterError` naming ``what`` (``backend
    encoders.sim``), the field and the parameters the factory takes, and
    :class:`~ubf_async.errors.PluginError` for a factory whose parameters cannot be described.
    """
    try:
        struct = parameters_of(factory, injected=injected)
    except (TypeError, ValueError) as exc:
        raise PluginError(f"{what}: its parameters cannot be described ({exc})") from None
    takes = struct.__struct_fields__
    if not isinstance(params, Mapping):
        raise ParameterError(what, f"Expected `object`, got `{type(params).__name__}`",
                             takes=takes)
    try:
        return msgspec.structs.asdict(msgspec.convert(dict(params), struct))
    except msgspec.ValidationError as exc:
        problem, at = validation_parts(exc)
        raise ParameterError(what, problem, at=at, takes=takes) from None


_VALIDATION_AT = re.compile(r"^(?P<problem>.*?)(?: - at `(?P<at>\$[^`]*)`)?$", re.S)


def validation_parts(exc: msgspec.ValidationError) -> tuple[str, str]:
    """msgspec's message split into the problem and the place (``$.tree.children[1]``; empty
    for the object decoded itself)."""
    match = _VALIDATION_AT.match(str(exc))
    assert match is not None  # the pattern matches any text
    return match.group("problem"), match.group("at") or ""


def _data_type(annotation: Any) -> Any:
    """``annotation`` if msgspec can decode data into it, else ``Any`` (e.g. a union with a
    ``Callable``): such a parameter is then checked by the factory itself."""
    try:
        msgspec.inspect.type_info(annotation)
    except (TypeError, ValueError):
        return Any
    return annotation


def accepts(factory: Callable[..., Any], parameter: str) -> bool:
    """Whether ``factory`` takes a keyword parameter ``parameter`` (or ``**kwargs``)."""
    params = inspect.signature(factory).parameters
    return parameter in params or any(
        p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values())
