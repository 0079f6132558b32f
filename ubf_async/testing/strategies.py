"""Hypothesis strategies of well-formed samples of every shipped topic, drawn from the types
the robot decodes with — so what they generate is exactly what the robot would accept — and of
states made of them, for property tests of a behaviour::

    from hypothesis import given
    from ubf_async.testing import strategies

    @given(strategies.states({"camera/front": topics.CAMERA}))
    def test_flee_never_drives_forward(state):
        action = Flee().act(state)
        assert action is None or action.speed <= 0

Needs ``hypothesis`` (the ``test`` extra brings it).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import msgspec
import msgspec.inspect as mi
from hypothesis import strategies as st

from ubf_async.core.state import Reading, State
from ubf_async.wire import topics
from ubf_async.wire.topics import Topic

__all__ = ["data_of", "messages", "states"]

_CHARACTERS = st.characters(codec="utf-8", exclude_categories=["Cs"])
_PLAIN_TEXT = st.text(_CHARACTERS, max_size=32)


def _bounds(info: mi.IntType | mi.FloatType) -> tuple[Any, Any]:
    """The lowest and highest value allowed (an int's strict bound moved by one)."""
    step = 1 if isinstance(info, mi.IntType) else 0
    low = info.ge if info.ge is not None else None if info.gt is None else info.gt + step
    high = info.le if info.le is not None else None if info.lt is None else info.lt - step
    return low, high


def data_of(info: mi.Type) -> st.SearchStrategy[Any]:
    """Values of one msgspec type, within its limits (what the wire's checks accept)."""
    if isinstance(info, mi.Metadata):
        return data_of(info.type)
    if isinstance(info, mi.IntType):
        low, high = _bounds(info)
        return st.integers(min_value=low, max_value=high)
    if isinstance(info, mi.FloatType):
        low, high = _bounds(info)
        return st.floats(min_value=low, max_value=high, allow_nan=False, allow_infinity=False,
                         exclude_min=info.gt is not None, exclude_max=info.lt is not None)
    if isinstance(info, mi.StrType):
        return st.text(_CHARACTERS, min_size=info.min_length or 0,
                       max_size=min(info.max_length or 32, 32))
    if isinstance(info, mi.BytesType):
        return st.binary(max_size=min(info.max_length or 64, 64))
    if isinstance(info, mi.BoolType):
        return st.booleans()
    if isinstance(info, mi.NoneType):
        return st.none()
    if isinstance(info, mi.LiteralType):
        return st.sampled_from(sorted(info.values, key=str))
    if isinstance(info, mi.UnionType):
        return st.one_of(*(data_of(t) for t in info.types))
    if isinstance(info, mi.VarTupleType | mi.ListType):
        low = info.min_length or 0
        items = st.lists(data_of(info.item_type), min_size=low,
                         max_size=min(info.max_length if info.max_length is not None
                                      else low + 4, low + 4))
        return items.map(tuple) if isinstance(info, mi.VarTupleType) else items
    if isinstance(info, mi.TupleType):
        return st.tuples(*(data_of(t) for t in info.item_types))
    if isinstance(info, mi.StructType):
        required = {f.name: data_of(f.type) for f in info.fields if f.required}
        optional = {f.name: data_of(f.type) for f in info.fields if not f.required}
        agree = _AGREE.get(info.cls, _as_given)
        return st.fixed_dictionaries(required, optional=optional).map(
            lambda fields: _built(info.cls, agree(fields))).filter(_is_built)
    if isinstance(info, mi.DictType):
        return st.dictionaries(_PLAIN_TEXT, st.integers(-1000, 1000), max_size=4)
    if isinstance(info, mi.AnyType):
        return st.none() | st.booleans() | st.integers(-1000, 1000) | _PLAIN_TEXT
    raise TypeError(f"no strategy for {info!r}")


def messages(topic: Topic[Any]) -> st.SearchStrategy[Any]:
    """Typed messages of ``topic`` (``topics.CAMERA`` → ``CameraSeekcolor``), each one the
    robot accepts. Fields that must agree are made to (a camera sample's ``total`` is its
    bins' sum, an LED mask lights no LED beyond the bank, a colour range's ``lo`` is under its
    ``hi``)."""
    return data_of(mi.type_info(topic.type))


def _as_given(fields: dict[str, Any]) -> dict[str, Any]:
    return fields


def _seek_color(fields: dict[str, Any]) -> dict[str, Any]:
    pairs = [sorted(pair) for pair in zip(fields["lo"], fields["hi"], strict=True)]
    return {**fields, "lo": tuple(p[0] for p in pairs), "hi": tuple(p[1] for p in pairs)}


_AGREE: dict[type, Any] = {
    topics.CameraSeekcolor: lambda f: {**f, "total": min(sum(f["bins"]), 16_777_216)},
    topics.LedState: lambda f: {**f, "mask": f["mask"] & ((1 << f["count"]) - 1)},
    topics.SeekColor: _seek_color,
}
"""Per message type: how drawn fields are made to agree with each other."""


class _NotBuilt:
    """Fields the type refused (a rule across fields no fix above knows)."""


def _built(cls: type, fields: dict[str, Any]) -> Any:
    try:  # through the codec's own checks (a struct's __post_init__ rules)
        return msgspec.convert(fields, cls)
    except (msgspec.ValidationError, ValueError):
        return _NotBuilt()


def _is_built(value: Any) -> bool:
    return not isinstance(value, _NotBuilt)


def states(sources: Mapping[str, Topic[Any]], *, stale: bool | None = False,
           now_s: float = 10.0) -> st.SearchStrategy[State]:
    """States holding a sample of each of ``sources`` (``{"range/front": topics.RANGE}``),
    fresh (``stale=False``), stale (``True``) or either (``None``), aged up to a second at
    ``now_s`` of robot time."""
    now_ns = round(now_s * 1e9)
    stale_flags = st.just(stale) if stale is not None else st.booleans()

    def reading(message: Any, age_s: float, is_stale: bool) -> Reading:
        return Reading(value=message, stamp_ns=now_ns - round(age_s * 1e9), seq=1,
                       age_s=age_s, stale=is_stale)

    readings = {source: st.builds(reading, messages(topic), st.floats(0.0, 1.0), stale_flags)
                for source, topic in sources.items()}
    return st.fixed_dictionaries(readings).map(lambda r: State(r, now_ns=now_ns))
