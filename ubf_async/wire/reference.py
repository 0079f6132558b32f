"""Every schema's fields as the code checks them: the reference a foreign implementer reads.

Drawn from the very types that decode the wire (:mod:`ubf_async.wire.topics`, through
msgspec's type information), so the page cannot drift from what a receiver accepts:
``docs/protocol.md`` holds :func:`markdown`'s output between :data:`BEGIN` and :data:`END`
(tests/test_protocol_reference.py compares them) and ``python -m ubf_async.inspector schemas``
prints it. Each field says whether a sender must give
it, its default when it may leave it out, its type and its limits.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

import msgspec
import msgspec.inspect as mi

from ubf_async.wire.topics import TOPICS, PlainData, Topic

__all__ = ["BEGIN", "END", "field_rows", "markdown", "plain", "type_text"]

BEGIN = "<!-- generated from the code's schemas: python -m ubf_async.inspector schemas -->"
END = "<!-- end of the generated schemas -->"

_INT_UNBOUNDED = 2**63 - 1
_FLOAT_UNBOUNDED = 1e300


def _number(value: float) -> str:
    for multiple, name in ((1, "π"), (0.5, "π/2")):
        if math.isclose(abs(value), math.pi * multiple):
            return ("−" if value < 0 else "") + name
    if isinstance(value, int) or float(value).is_integer():
        text = f"{int(value)}" if abs(value) < 1e15 else f"{value:g}"
    else:
        text = f"{value:g}"
    return text.replace("-", "−")


def _bounds(info: mi.IntType | mi.FloatType) -> str:
    huge = _INT_UNBOUNDED if isinstance(info, mi.IntType) else _FLOAT_UNBOUNDED
    low = (info.ge, "≥") if info.ge is not None else (info.gt, ">")
    high = (info.le, "≤") if info.le is not None else (info.lt, "<")
    has_low = low[0] is not None and abs(low[0]) < huge
    has_high = high[0] is not None and abs(high[0]) < huge
    if has_low and has_high and low[1] == "≥" and high[1] == "≤":
        return f" {_number(low[0])}…{_number(high[0])}"  # type: ignore[arg-type]
    parts = ([f"{low[1]} {_number(low[0])}"] if has_low else []) + (  # type: ignore[arg-type]
        [f"{high[1]} {_number(high[0])}"] if has_high else [])  # type: ignore[arg-type]
    return (" " + ", ".join(parts)) if parts else ""


def _length(info: Any, unit: str = "") -> str:
    low, high = getattr(info, "min_length", None), getattr(info, "max_length", None)
    if low is not None and low == high:
        return f" of exactly {low}{unit}"
    if low and high is not None:
        return f" of {low}…{high}{unit}"
    if high is not None:
        return f" ≤ {high}{unit}"
    return f" ≥ {low}{unit}" if low else ""


def type_text(info: mi.Type, within: tuple[type, ...] = ()) -> str:
    """One field's type and limits in the page's words: ``int 0…255``, ``str ≤ 128``,
    ``"yes" | "no"``, ``array of exactly 5 items of int ≥ 0`` … ``within``: the maps being
    described around it (a map that holds maps of its own shape says so)."""
    if isinstance(info, mi.Metadata):
        return type_text(info.type, within)
    if isinstance(info, mi.IntType):
        return "int" + _bounds(info)
    if isinstance(info, mi.FloatType):
        return "number" + _bounds(info)
    if isinstance(info, mi.StrType):
        return "str" + _length(info)
    if isinstance(info, mi.BytesType | mi.ByteArrayType | mi.MemoryViewType):
        return "bytes" + _length(info)
    if isinstance(info, mi.BoolType):
        return "bool"
    if isinstance(info, mi.NoneType):
        return "nil"
    if isinstance(info, mi.LiteralType):
        return " | ".join(f'`"{v}"`' if isinstance(v, str) else f"`{v}`"
                            for v in sorted(info.values, key=str))
    if isinstance(info, mi.UnionType):
        kinds = [t for t in info.types if not isinstance(t, mi.NoneType)]
        text = " or ".join(type_text(t, within) for t in kinds)
        return text + (" or nil" if len(kinds) < len(info.types) else "")
    if isinstance(info, mi.ListType | mi.VarTupleType | mi.SetType | mi.FrozenSetType):
        return f"array{_length(info, ' items')} of {type_text(info.item_type, within)}"
    if isinstance(info, mi.TupleType):
        return "array [" + ", ".join(type_text(t, within) for t in info.item_types) + "]"
    if isinstance(info, mi.StructType):
        if info.cls in within:
            return "map of the same shape"
        return "map {" + ", ".join(
            f"{f.encode_name}{'' if f.required else '?'}: {type_text(f.type, (*within, info.cls))}"
            for f in info.fields) + "}"
    if isinstance(info, mi.DictType):
        return (f"map of {type_text(info.key_type, within)} to "
                f"{type_text(info.value_type, within)}")
    if isinstance(info, mi.AnyType):
        return "any plain value"
    return type(info).__name__.removesuffix("Type").lower()


def _default(field: mi.Field) -> str:
    default = field.default
    if default is msgspec.NODEFAULT and field.default_factory is not msgspec.NODEFAULT:
        default = field.default_factory()
    if default is None or default is msgspec.NODEFAULT:
        return "*opt*"
    if isinstance(default, str):
        return f'*opt*, default `"{default}"`'
    if isinstance(default, bool):
        return f"*opt*, default `{str(default).lower()}`"
    if isinstance(default, tuple | list):
        return "*opt*, default `[]`" if not default else f"*opt*, default `{list(default)}`"
    return f"*opt*, default `{default}`"


def plain(text: str) -> str:
    """A cell of the reference without its Markdown (for a terminal)."""
    return text.translate(_MARKS)


_MARKS = str.maketrans("", "", "`*\\")


def field_rows(topic: Topic[Any]) -> list[tuple[str, str, str]]:
    """``(field, required or optional with its default, type)`` of ``topic``'s data; empty
    for free-form data."""
    if topic.type is PlainData:
        return []
    info = mi.type_info(topic.type)
    assert isinstance(info, mi.StructType), topic.name
    return [(f"`{f.encode_name}`", "required" if f.required else _default(f),
             type_text(f.type, (info.cls,))) for f in info.fields]


def _key(topic: Topic[Any]) -> str:
    return "`" + topic.pattern.replace("{", "<").replace("}", ">") + "`"


def markdown(topics: Iterable[Topic[Any]] = TOPICS) -> str:
    """Each topic's schema name, key, and a table of its fields (the page's reference)."""
    blocks = []
    for topic in topics:
        head = f"**`{topic.schema}`** on {_key(topic)} — {topic.doc}"
        rows = field_rows(topic)
        if topic.type is PlainData:
            blocks.append(f"{head}: a free-form map of plain values.")
        elif not rows:
            blocks.append(f"{head}: no fields (`{{}}`).")
        else:
            table = ["| field | given | type |", "|---|---|---|"]
            table += [f"| {name} | {given} | {kind.replace('|', chr(92) + '|')} |"
                      for name, given, kind in rows]
            blocks.append(head + ":\n\n" + "\n".join(table))
    return "\n\n".join(blocks) + "\n"
