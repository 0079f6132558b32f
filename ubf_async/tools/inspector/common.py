"""What the inspector's verbs share: a key as given on the command line resolved under the
robot's prefix, a sample decoded and validated as the robot does, values printed as JSON, and
which live components announce publishing a key (their heartbeats)."""

from __future__ import annotations

import json
from typing import Any

import msgspec

from ubf_async.cli import run
from ubf_async.net.keyexpr import intersects
from ubf_async.runtime.component import HealthMonitor
from ubf_async.wire import topics
from ubf_async.wire.keys import Keys
from ubf_async.wire.protocol import Message, decode

__all__ = ["HEARD_WITHIN_S", "KEY_HELP", "PROG", "announcing", "decode_for", "expected_schema",
           "jsonable", "key_or_report", "number", "resolve_key", "say_error", "to_json"]

PROG = "python -m ubf_async.inspector"

HEARD_WITHIN_S = 5.0
"""How much longer ``echo`` and ``info`` wait, at most, for a heartbeat of every live
component before they say who publishes what (on a busy machine they can be late)."""
KEY_HELP = ("a key or key expression, relative to ubf/<robot>/ unless it starts with ubf/ "
            "(e.g. cmd/drive, 'sensor/**')")
"""The help of a KEY argument taking a key expression (hz, bw, info)."""


def say_error(message: object) -> None:
    """``python -m ubf_async.inspector: error: …`` on stderr: the one format of an error."""
    run.say_error(PROG, message)


def expected_schema(keys: Keys, key: str) -> str | None:
    """The schema a key requires (``cmd/drive`` → ``drive``, ``sensor/camera/x`` →
    ``camera.seekcolor``), from :mod:`ubf_async.wire.topics`; ``None`` where any is allowed (a
    kind of sensor not declared there, a status key)."""
    schemas = {topic.schema for topic in topics.matching(keys, key)}
    return schemas.pop() if len(schemas) == 1 else None


def decode_for(keys: Keys, key: str, payload: bytes) -> Message:
    """Decode and validate a sample as its key requires (raises :class:`ProtocolError`)."""
    return decode(payload, schema=expected_schema(keys, key))


def resolve_key(keys: Keys, key: str) -> str:
    """``sensor/range/front`` → ``ubf/<robot>/sensor/range/front``; full keys stay as they are."""
    key = key.strip().strip("/")
    if not key:
        raise ValueError("empty key")
    return key if key.startswith("ubf/") or key.startswith("**") else f"{keys.prefix}/{key}"


def key_or_report(keys: Keys, key: str) -> str | None:
    """:func:`resolve_key`, or ``None`` once the error is printed on stderr (the verb then
    exits 2)."""
    try:
        return resolve_key(keys, key)
    except ValueError as exc:
        say_error(exc)
        return None


def jsonable(value: Any) -> Any:
    """``value`` as JSON can carry it: typed messages as their fields, bytes as hex."""
    if isinstance(value, msgspec.Struct):  # a typed message: its fields as on the wire
        return jsonable(msgspec.to_builtins(value))
    if isinstance(value, bytes):
        return value.hex()
    if isinstance(value, dict):
        return {str(k): jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [jsonable(v) for v in value]
    return value


def to_json(value: Any) -> str:
    """One line of JSON for ``value`` (:func:`jsonable`)."""
    return json.dumps(jsonable(value), ensure_ascii=False)


def number(value: Any) -> float | None:
    """A status field read as a number, ``None`` if it is not one."""
    return float(value) if isinstance(value, int | float) else None


def announcing(monitor: HealthMonitor, key_expr: str, alive: set[str]
               ) -> dict[str, list[topics.Published]]:
    """The live components whose newest heartbeat announces a key matching ``key_expr``
    (``publishes``, docs/protocol.md), with what they announce there (a component whose
    liveliness token is gone is not a publisher any more)."""
    found: dict[str, list[topics.Published]] = {}
    for component, health in monitor.components.items():
        if component in alive and (
                hits := [p for p in health.publishes if intersects(key_expr, p.key)]):
            found[component] = hits
    return found
