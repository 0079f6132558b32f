"""Fuzzing the wire contract: every topic's decoder and encoder, and the generic path.

For every topic in :data:`ubf_async.wire.topics.TOPICS` (iterated, so a new topic is fuzzed
without touching this file) and for a schema not declared there, ``protocol.decode`` and
``protocol.encode`` are fed random bytes, valid msgpack of wrong shapes, envelopes with
mutated fields, and valid data (built from the topic's type with ``msgspec.inspect``) with
one part mutated: NaN, ±inf, integers at and beyond the int64/uint64 edges, 1 MB strings,
long arrays, extension types, bin for str and str for bin, missing and unknown fields,
10 000 levels of nesting (as raw msgpack bytes, which no packer would build).

What must hold: the only exception that escapes is ``ProtocolError``; whatever is accepted
respects the declared bounds (floats finite and in range, strings and arrays within their
``max_length``, the payload within ``MAX_PAYLOAD_BYTES``) and round-trips (re-encoded, it
decodes to the same message); and valid data, packed by plain ``msgpack`` as a client
following docs/protocol.md would, is accepted.

Hypothesis runs derandomized (the same examples in every run, no example database), so a
failure in CI reproduces locally; 12 examples per test and topic keep the file near 15 s.
``UBF_FUZZ_EXAMPLES=500`` fuzzes deeper.
"""

from __future__ import annotations

import contextlib
import math
import os
from collections.abc import Callable
from typing import Any

import msgpack
import msgspec
import msgspec.inspect as mi
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ubf_async.errors import ProtocolError
from ubf_async.wire import topics
from ubf_async.wire.protocol import MAX_PAYLOAD_BYTES, PROTOCOL_VERSION, Message, decode, encode
from ubf_async.wire.topics import (
    INT64_MAX,
    MAX_CONTAINER_LEN,
    MAX_DEPTH,
    MAX_STR_LEN,
    TOPICS,
    PlainData,
    Topic,
)

GENERIC_SCHEMA = "fuzz.newkind"
"""A schema declared nowhere: its data takes the generic path."""
assert GENERIC_SCHEMA not in topics.BY_SCHEMA

# Every declared topic, and ``None`` for the generic path.
CASES: list[Topic[Any] | None] = [*TOPICS, None]
IDS = [t.name if t is not None else "generic" for t in CASES]

FUZZ = settings(max_examples=int(os.environ.get("UBF_FUZZ_EXAMPLES", "12")), deadline=None,
                derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                       HealthCheck.filter_too_much])
ONE_MB = 1 << 20


def schema_of(topic: Topic[Any] | None) -> str:
    return topic.schema if topic is not None else GENERIC_SCHEMA


def type_of(topic: Topic[Any] | None) -> Any:
    return topic.type if topic is not None else PlainData


def pack(value: Any) -> bytes:
    """As a plain msgpack client packs (``msgpack.packb`` defaults: str as str, bytes as bin)."""
    return msgpack.packb(value, use_bin_type=True)


def envelope(schema: str, data: Any, **fields: Any) -> dict[str, Any]:
    return {"schema": schema, "v": PROTOCOL_VERSION, "stamp_ns": 1_000, "seq": 1, "data": data,
            **fields}


def raw_envelope(schema: str, data_bytes: bytes) -> bytes:
    """An envelope whose ``data`` is the given msgpack bytes, verbatim."""
    head = {"schema": schema, "v": PROTOCOL_VERSION, "stamp_ns": 1_000, "seq": 1}
    return (bytes([0x80 | (len(head) + 1)]) + b"".join(pack(k) + pack(v) for k, v in head.items())
            + pack("data") + data_bytes)


# ---------------------------------------------------------------------------------------------
# What an accepted message must satisfy


def check_plain(value: Any, path: str = "data", depth: int = 0) -> None:
    """The generic rules (docs/protocol.md, *Payload: the envelope*: its limits)."""
    assert depth <= MAX_DEPTH, f"{path}: nested deeper than {MAX_DEPTH}"
    if value is None or isinstance(value, bool | bytes):
        return
    if isinstance(value, int):
        assert -INT64_MAX <= value <= INT64_MAX, f"{path}: {value} outside int64"
    elif isinstance(value, float):
        assert math.isfinite(value), f"{path}: {value} accepted"
    elif isinstance(value, str):
        assert len(value) <= MAX_STR_LEN, f"{path}: string of {len(value)}"
    elif isinstance(value, list | tuple):
        assert len(value) <= MAX_CONTAINER_LEN, f"{path}: array of {len(value)}"
        for i, item in enumerate(value):
            check_plain(item, f"{path}[{i}]", depth + 1)
    elif isinstance(value, dict):
        assert len(value) <= MAX_CONTAINER_LEN, f"{path}: map of {len(value)}"
        for key, item in value.items():
            assert isinstance(key, str), f"{path}: key {key!r}"
            check_plain(item, f"{path}.{key}", depth + 1)
    else:
        raise AssertionError(f"{path}: {type(value).__name__} accepted")


def _in_range(value: float, t: mi.IntType | mi.FloatType) -> bool:
    return ((t.ge is None or value >= t.ge) and (t.gt is None or value > t.gt)
            and (t.le is None or value <= t.le) and (t.lt is None or value < t.lt))


def check_typed(value: Any, t: mi.Type, path: str = "data") -> None:
    """``value`` (decoded) respects the constraints of its type info ``t``."""
    if isinstance(t, mi.Metadata):
        check_typed(value, t.type, path)
    elif isinstance(t, mi.AnyType):
        check_plain(value, path)
    elif isinstance(t, mi.NoneType):
        assert value is None, f"{path}: {value!r} for nil"
    elif isinstance(t, mi.BoolType):
        assert isinstance(value, bool), f"{path}: {value!r} for bool"
    elif isinstance(t, mi.IntType):
        assert isinstance(value, int) and not isinstance(value, bool), f"{path}: {value!r}"
        assert -INT64_MAX <= value <= INT64_MAX and _in_range(value, t), f"{path}: {value}"
    elif isinstance(t, mi.FloatType):
        assert isinstance(value, float), f"{path}: {value!r} for float"
        assert math.isfinite(value) and _in_range(value, t), f"{path}: {value} accepted"
    elif isinstance(t, mi.StrType):
        assert isinstance(value, str), f"{path}: {value!r} for str"
        assert len(value) <= (t.max_length or MAX_STR_LEN), f"{path}: string of {len(value)}"
    elif isinstance(t, mi.BytesType):
        assert isinstance(value, bytes), f"{path}: {value!r} for bytes"
    elif isinstance(t, mi.LiteralType):
        assert value in t.values, f"{path}: {value!r} not one of {t.values}"
    elif isinstance(t, mi.UnionType):
        problems = []
        for option in t.types:
            try:
                check_typed(value, option, path)
                return
            except AssertionError as exc:
                problems.append(str(exc))
        raise AssertionError(f"{path}: fits no type of the union: {problems}")
    elif isinstance(t, mi.VarTupleType | mi.ListType | mi.TupleType):
        assert isinstance(value, tuple | list), f"{path}: {value!r} for an array"
        items = (t.item_types if isinstance(t, mi.TupleType)
                 else (t.item_type,) * len(value))
        assert len(items) == len(value), f"{path}: {len(value)} items"
        if not isinstance(t, mi.TupleType):
            assert (t.min_length or 0) <= len(value) <= (t.max_length or MAX_CONTAINER_LEN)
        for i, (item, item_t) in enumerate(zip(value, items, strict=True)):
            check_typed(item, item_t, f"{path}[{i}]")
    elif isinstance(t, mi.DictType):
        assert isinstance(value, dict), f"{path}: {value!r} for a map"
        assert len(value) <= (t.max_length or MAX_CONTAINER_LEN), f"{path}: map of {len(value)}"
        for key, item in value.items():
            check_typed(key, t.key_type, f"{path}<key>")
            check_typed(item, t.value_type, f"{path}.{key}")
    elif isinstance(t, mi.StructType):
        assert isinstance(value, t.cls), f"{path}: {type(value).__name__} for {t.cls.__name__}"
        for f in t.fields:
            check_typed(getattr(value, f.name), f.type, f"{path}.{f.name}")
    else:
        raise AssertionError(f"{path}: no check for {t!r}")


def check_accepted(message: Message[Any], payload: bytes) -> None:
    """Bounds and round trip of a message ``decode`` accepted."""
    assert len(payload) <= MAX_PAYLOAD_BYTES
    assert message.version == PROTOCOL_VERSION
    assert 0 <= message.stamp_ns <= INT64_MAX and 0 <= message.seq <= INT64_MAX
    assert message.pub is None or 1 <= message.pub <= INT64_MAX
    assert message.period_s is None or 1e-6 <= message.period_s <= 3600.0
    topic = topics.BY_SCHEMA.get(message.schema)
    kind = topic.type if topic is not None else PlainData
    if kind is PlainData:
        assert isinstance(message.data, dict)
        check_plain(message.data)
    else:
        check_typed(message.data, mi.type_info(kind))
    again = encode(message.schema, message.data, stamp_ns=message.stamp_ns, seq=message.seq,
                   period_s=message.period_s, pub=message.pub)
    assert decode(again, schema=message.schema) == message
    assert decode(again, topic=topic) == message if topic is not None else True


def decode_all_ways(payload: bytes, topic: Topic[Any] | None) -> list[Message[Any]]:
    """Decode ``payload`` as a key of ``topic`` would and with no expectation; only
    ``ProtocolError`` may escape; what is accepted is checked."""
    accepted = []
    attempts: list[Callable[[], Message[Any]]] = [
        lambda: decode(payload),
        (lambda: decode(payload, topic=topic)) if topic is not None
        else (lambda: decode(payload, schema=GENERIC_SCHEMA)),
        lambda: decode(bytearray(payload)),
    ]
    for attempt in attempts:
        try:
            message = attempt()
        except ProtocolError as exc:
            assert str(exc), "a ProtocolError says what is wrong"
            continue
        check_accepted(message, payload)
        accepted.append(message)
    return accepted


# ---------------------------------------------------------------------------------------------
# Strategies


def plain_values(levels: int = 2) -> st.SearchStrategy[Any]:
    """Valid generic values (docs/protocol.md): nil, bool, int64, finite float, str, bytes,
    arrays, str-keyed maps, ``levels`` deep."""
    leaves = (st.none() | st.booleans() | st.integers(-INT64_MAX, INT64_MAX)
              | st.floats(allow_nan=False, allow_infinity=False) | st.text(max_size=12)
              | st.binary(max_size=12))
    if levels <= 0:
        return leaves
    inner = plain_values(levels - 1)
    return leaves | st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=8), inner,
                                                                    max_size=3)


def _post_init_fixups() -> dict[type, Callable[[dict[str, Any]], dict[str, Any]]]:
    """Make generated maps satisfy the cross-field rules of messages whose ``__post_init__``
    checks more than msgspec's annotations can say."""

    def seek_color(d: dict[str, Any]) -> dict[str, Any]:
        lo = [min(a, b) for a, b in zip(d["lo"], d["hi"], strict=True)]
        hi = [max(a, b) for a, b in zip(d["lo"], d["hi"], strict=True)]
        return {**d, "lo": lo, "hi": hi}

    def tree_request(d: dict[str, Any]) -> dict[str, Any]:
        if "tree" in d and not isinstance(d["tree"], str | bytes):
            d = {**d, "tree": repr(d["tree"])[:MAX_STR_LEN]}
        required, optional = topics.TREE_OPS[d["op"]]
        if any(d.get(name) is None for name in required) or (
                d["op"] == "set_child" and d.get("priority") is None
                and d.get("weight") is None):
            return {"op": "show"}
        return {k: v for k, v in d.items() if k == "op" or k in (*required, *optional)}

    def tree_reply(d: dict[str, Any]) -> dict[str, Any]:
        d = dict(d)
        if d["ok"] and d.get("tree") is None:
            d["ok"] = False
        if not d["ok"] and d.get("error") is None:
            d["error"] = "refused"
        return d

    def led_state(d: dict[str, Any]) -> dict[str, Any]:
        return {**d, "mask": d["mask"] & ((1 << d["count"]) - 1)}

    return {topics.SeekColor: seek_color, topics.TreeRequest: tree_request,
            topics.TreeReply: tree_reply, topics.LedState: led_state}


FIXUPS = _post_init_fixups()
NESTED_STRUCTS = 3
"""How deep generated valid values nest structs (TreeNode is recursive)."""


def valid_values(t: mi.Type, depth: int = 0) -> st.SearchStrategy[Any]:
    """Values a plain msgpack client may send for the type info ``t`` (as builtins)."""
    if isinstance(t, mi.Metadata):
        return valid_values(t.type, depth)
    if isinstance(t, mi.AnyType):
        return plain_values()
    if isinstance(t, mi.NoneType):
        return st.none()
    if isinstance(t, mi.BoolType):
        return st.booleans()
    if isinstance(t, mi.IntType):
        lo = t.ge if t.ge is not None else (t.gt + 1 if t.gt is not None else -INT64_MAX)
        hi = t.le if t.le is not None else (t.lt - 1 if t.lt is not None else INT64_MAX)
        return st.integers(lo, hi)
    if isinstance(t, mi.FloatType):
        lo = t.ge if t.ge is not None else t.gt
        hi = t.le if t.le is not None else t.lt
        floats = st.floats(min_value=lo, max_value=hi, exclude_min=t.gt is not None,
                           exclude_max=t.lt is not None, allow_nan=False, allow_infinity=False)
        # An int is a valid "number" too (docs/protocol.md).
        least = max(math.ceil(lo), -2**53) if lo is not None else -2**53
        most = min(math.floor(hi), 2**53) if hi is not None else 2**53
        if least > most:
            return floats
        return floats | st.integers(least, most).filter(lambda i: _in_range(i, t))
    if isinstance(t, mi.StrType):
        most = t.max_length if t.max_length is not None else MAX_STR_LEN
        short = st.text(min_size=t.min_length or 0, max_size=min(most, 16))
        return short | st.just("é" * most)  # the longest allowed, 2 bytes a character
    if isinstance(t, mi.BytesType):
        return st.binary(max_size=16)
    if isinstance(t, mi.LiteralType):
        return st.sampled_from(t.values)
    if isinstance(t, mi.UnionType):
        options = t.types
        if depth >= NESTED_STRUCTS and any(isinstance(o, mi.NoneType) for o in options):
            return st.none()
        return st.one_of(*(valid_values(o, depth) for o in options))
    if isinstance(t, mi.VarTupleType | mi.ListType):
        least = t.min_length or 0
        most = least if depth >= NESTED_STRUCTS else max(least, min(t.max_length or 3, 3))
        return st.lists(valid_values(t.item_type, depth), min_size=least, max_size=most)
    if isinstance(t, mi.TupleType):
        return st.tuples(*(valid_values(i, depth) for i in t.item_types)).map(list)
    if isinstance(t, mi.DictType):
        return st.dictionaries(valid_values(t.key_type, depth), valid_values(t.value_type, depth),
                               min_size=t.min_length or 0, max_size=3)
    if isinstance(t, mi.StructType):
        required = {f.encode_name: valid_values(f.type, depth + 1)
                    for f in t.fields if f.required}
        optional = {f.encode_name: valid_values(f.type, depth + 1)
                    for f in t.fields if not f.required}
        maps = st.fixed_dictionaries(required, optional=optional)
        fixup = FIXUPS.get(t.cls)
        return maps.map(fixup) if fixup is not None else maps
    raise AssertionError(f"no strategy for {t!r}: teach valid_values about it")


def valid_data(topic: Topic[Any] | None) -> st.SearchStrategy[Any]:
    return valid_values(mi.type_info(type_of(topic)))


def simplest(t: mi.Type) -> Any:
    """The simplest valid value of the type info ``t`` (required fields only)."""
    if isinstance(t, mi.Metadata):
        return simplest(t.type)
    if isinstance(t, mi.IntType | mi.FloatType):
        lo = next((b for b in (t.ge, t.gt) if b is not None), -math.inf)
        hi = next((b for b in (t.le, t.lt) if b is not None), math.inf)
        value = min(max(0, lo), hi) + (1 if t.gt is not None and t.gt >= 0 else 0)
        return int(value) if isinstance(t, mi.IntType) else float(value)
    if isinstance(t, mi.StrType):
        return "s" * (t.min_length or 1)
    if isinstance(t, mi.LiteralType):
        return sorted(t.values, key=repr)[0]
    if isinstance(t, mi.UnionType):
        return simplest(next((o for o in t.types if not isinstance(o, mi.NoneType)), t.types[0]))
    if isinstance(t, mi.VarTupleType | mi.ListType):
        return [simplest(t.item_type)] * (t.min_length or 0)
    if isinstance(t, mi.TupleType):
        return [simplest(item) for item in t.item_types]
    if isinstance(t, mi.StructType):
        value = {f.encode_name: simplest(f.type) for f in t.fields if f.required}
        fixup = FIXUPS.get(t.cls)
        return fixup(value) if fixup is not None else value
    return {mi.NoneType: None, mi.BoolType: False, mi.BytesType: b"", mi.AnyType: None,
            mi.DictType: {}}[type(t)]


def example_data(topic: Topic[Any] | None) -> dict[str, Any]:
    """A valid ``data`` map of ``topic`` (the generic path: a small map)."""
    if topic is None or topic.type is PlainData:
        return {"x": 1}
    value = simplest(mi.type_info(topic.type))
    msgspec.convert(value, topic.type)  # valid, or the test's own construction is wrong
    return value


# Values of every msgpack type, valid for nothing in particular.
WILD_LEAVES = (
    st.none() | st.booleans() | st.integers(-2**63, 2**64 - 1)
    | st.floats()  # NaN and ±inf included
    | st.builds(msgpack.ExtType, st.integers(0, 127), st.binary(max_size=12))
    | st.builds(msgpack.Timestamp, st.integers(0, 2**34 - 1), st.integers(0, 999_999_999))
    | st.text(max_size=20) | st.binary(max_size=20)
)
WILD_KEYS = st.text(max_size=8) | st.integers(-2**63, 2**64 - 1) | st.binary(max_size=4) \
    | st.none() | st.booleans() | st.floats()
WILD = st.recursive(WILD_LEAVES, lambda inner: st.lists(inner, max_size=4)
                    | st.dictionaries(WILD_KEYS, inner, max_size=4), max_leaves=16)


def field_names(topic: Topic[Any] | None) -> list[str]:
    return list(topic.fields) if topic is not None and topic.fields else ["x"]


# Values that break something: types, ranges, finiteness, sizes, encodings.
NASTY = st.sampled_from([
    math.nan, math.inf, -math.inf, -0.0, 1.7e308, -1.7e308, 5e-324, 3.1416,
    2**63 - 1, 2**63, 2**64 - 1, -2**63, -2**63 + 1, -1, 0, 1, 256, 100_001, (1 << 24) + 1,
    True, False, None, "", b"", [], {}, [None], {"": None},
    "x" * 33, "x" * 65, "x" * 129, "x" * 257, "x" * (MAX_STR_LEN + 1), "é" * MAX_STR_LEN,
    "x" * ONE_MB, b"x" * ONE_MB, list(range(MAX_CONTAINER_LEN + 1)), [0] * 5000,
    {str(i): i for i in range(MAX_CONTAINER_LEN + 1)},
    msgpack.ExtType(1, b"\x00"), msgpack.Timestamp(1, 0),
    "ok", "composite", "show", "load",
]) | WILD


@st.composite
def mutated(draw: st.DrawFn, value: Any) -> Any:
    """``value`` with one part changed: replaced by a nasty value, removed, an unknown field
    added, bin for str or str for bin."""
    if isinstance(value, dict) and value and draw(st.integers(0, 4)) > 0:
        key = draw(st.sampled_from(sorted(value, key=repr)))
        how = draw(st.sampled_from(["descend", "descend", "delete", "add"]))
        if how == "delete":
            return {k: v for k, v in value.items() if k != key}
        if how == "add":
            return {**value, draw(st.text(max_size=8) | WILD_KEYS): draw(NASTY)}
        return {**value, key: draw(mutated(value[key]))}
    if isinstance(value, list) and value and draw(st.integers(0, 4)) > 0:
        i = draw(st.integers(0, len(value) - 1))
        return [*value[:i], draw(mutated(value[i])), *value[i + 1:]]
    if isinstance(value, str) and draw(st.booleans()):
        return value.encode()
    if isinstance(value, bytes) and draw(st.booleans()):
        return value.decode("latin-1")
    return draw(NASTY)


NASTY_STAMPS = st.sampled_from([0, 1, INT64_MAX, -1, 2**63, 2**64 - 1, -2**63, 1.5, math.nan,
                                True, "1", None, b"\x01"])
NASTY_PERIODS = st.sampled_from([0.05, 1e-6, 3600, 5, 0, -1.0, 1e-7, 3600.5, math.nan,
                                 math.inf, -math.inf, True, "0.05", 2**64 - 1])
NASTY_PUBS = st.sampled_from([1, INT64_MAX, 0, -1, 2**63, 2**64 - 1, True, 1.0, "1"])
NASTY_VERSIONS = st.sampled_from([0, 2, -1, 1000, 1001, 2**64 - 1, -2**63, 1.0, True, "1",
                                  None, [1]])
NASTY_SCHEMAS = st.sampled_from(["", "x" * 64, "x" * 65, "drive", "range", "vote",
                                 GENERIC_SCHEMA, b"range", 1, None, ["range"]])


@st.composite
def mutated_envelopes(draw: st.DrawFn, topic: Topic[Any] | None) -> dict[Any, Any]:
    env: dict[Any, Any] = envelope(schema_of(topic), draw(valid_data(topic)),
                                   period_s=0.05, pub=7)
    for _ in range(draw(st.integers(1, 3))):
        field = draw(st.sampled_from(["schema", "v", "stamp_ns", "seq", "period_s", "pub",
                                      "data", "missing", "unknown"]))
        if field == "missing":
            env.pop(draw(st.sampled_from(sorted(env, key=repr))), None)
        elif field == "unknown":
            env[draw(WILD_KEYS)] = draw(WILD)
        else:
            env[field] = draw({
                "schema": NASTY_SCHEMAS, "v": NASTY_VERSIONS, "stamp_ns": NASTY_STAMPS,
                "seq": NASTY_STAMPS, "period_s": NASTY_PERIODS, "pub": NASTY_PUBS,
                "data": NASTY,
            }[field])
    return env


# ---------------------------------------------------------------------------------------------
# The contract itself


@pytest.mark.parametrize("topic", TOPICS, ids=[t.name for t in TOPICS])
def test_every_field_of_every_topic_is_bounded(topic: Topic[Any]) -> None:
    """The conventions of ubf_async.wire.topics, checked on the type info: every float bounded
    (msgspec lets NaN and ±inf through a plain ``float``), every string and array with a
    ``max_length``; generic data (``Any``) is checked by ``plain``."""
    seen: set[type] = set()

    def walk(t: mi.Type, path: str) -> None:
        if isinstance(t, mi.Metadata):
            walk(t.type, path)
        elif isinstance(t, mi.FloatType):
            assert (t.ge is not None or t.gt is not None) and (
                t.le is not None or t.lt is not None), f"{path}: unbounded float"
            assert all(math.isfinite(b) for b in (t.ge, t.gt, t.le, t.lt) if b is not None)
        elif isinstance(t, mi.IntType):
            assert (t.ge is not None or t.gt is not None) and (
                t.le is not None or t.lt is not None), f"{path}: unbounded int"
        elif isinstance(t, mi.StrType | mi.BytesType):
            assert t.max_length is not None, f"{path}: no max_length"
        elif isinstance(t, mi.VarTupleType | mi.ListType):
            assert t.max_length is not None, f"{path}: array without max_length"
            walk(t.item_type, f"{path}[]")
        elif isinstance(t, mi.TupleType):  # fixed length: bounded by its items
            for i, item in enumerate(t.item_types):
                walk(item, f"{path}[{i}]")
        elif isinstance(t, mi.UnionType):
            for option in t.types:
                walk(option, path)
        elif isinstance(t, mi.DictType):
            walk(t.key_type, f"{path}<key>")
            walk(t.value_type, f"{path}{{}}")
        elif isinstance(t, mi.StructType) and t.cls not in seen:
            seen.add(t.cls)
            for f in t.fields:
                walk(f.type, f"{path}.{f.name}")

    walk(mi.type_info(topic.type), topic.schema)


# ---------------------------------------------------------------------------------------------
# Decoding


@pytest.mark.parametrize("topic", CASES, ids=IDS)
@FUZZ
@given(data=st.data())
def test_valid_data_from_a_plain_msgpack_client_is_accepted_and_round_trips(
        topic: Topic[Any] | None, data: st.DataObject) -> None:
    value = data.draw(valid_data(topic), label="data")
    extra = data.draw(st.fixed_dictionaries({}, optional={
        "period_s": st.floats(1e-6, 3600.0), "pub": st.integers(1, INT64_MAX)}))
    stamp_ns = data.draw(st.integers(0, INT64_MAX))
    payload = pack({**envelope(schema_of(topic), value, **extra), "stamp_ns": stamp_ns})
    if len(payload) > MAX_PAYLOAD_BYTES:  # long strings in many fields: refused, and right so
        with pytest.raises(ProtocolError, match="exceeds"):
            decode(payload)
        return
    if topic is not None:
        message = decode(payload, topic=topic)
        assert isinstance(message.data, topic.type if topic.type is not PlainData else dict)
    else:
        message = decode(payload, schema=GENERIC_SCHEMA)
    assert message.schema == schema_of(topic) and message.stamp_ns == stamp_ns
    check_accepted(message, payload)
    # And a map of the fields, as a client would hand it to encode, gives the same message.
    again = encode(schema_of(topic), value, stamp_ns=stamp_ns, seq=1, **extra)
    assert decode(again, schema=schema_of(topic)) == message


@pytest.mark.parametrize("topic", CASES, ids=IDS)
@FUZZ
@given(payload=st.binary(max_size=300))
def test_random_bytes(topic: Topic[Any] | None, payload: bytes) -> None:
    decode_all_ways(payload, topic)


@pytest.mark.parametrize("topic", CASES, ids=IDS)
@FUZZ
@given(data=st.data())
def test_corrupted_valid_payloads(topic: Topic[Any] | None, data: st.DataObject) -> None:
    """A valid payload truncated, extended, or with bytes overwritten."""
    payload = bytearray(pack(envelope(schema_of(topic), data.draw(valid_data(topic)))))
    how = data.draw(st.sampled_from(["truncate", "append", "overwrite"]))
    if how == "truncate":
        del payload[data.draw(st.integers(0, len(payload) - 1)):]
    elif how == "append":
        payload += data.draw(st.binary(min_size=1, max_size=8))
    else:
        for _ in range(data.draw(st.integers(1, 4))):
            payload[data.draw(st.integers(0, len(payload) - 1))] = data.draw(st.integers(0, 255))
    decode_all_ways(bytes(payload), topic)


@pytest.mark.parametrize("topic", CASES, ids=IDS)
@FUZZ
@given(data=st.data())
def test_valid_msgpack_of_wrong_shapes(topic: Topic[Any] | None, data: st.DataObject) -> None:
    """Any msgpack value as the payload, as the data, and maps of the topic's own field
    names holding any msgpack value."""
    wild = data.draw(WILD, label="wild")
    decode_all_ways(pack(wild), topic)
    decode_all_ways(pack(envelope(schema_of(topic), wild)), topic)
    shaped = data.draw(st.dictionaries(st.sampled_from(field_names(topic)) | WILD_KEYS, WILD,
                                       max_size=6), label="shaped")
    decode_all_ways(pack(envelope(schema_of(topic), shaped)), topic)


@pytest.mark.parametrize("topic", CASES, ids=IDS)
@FUZZ
@given(data=st.data())
def test_valid_data_with_one_part_mutated(topic: Topic[Any] | None, data: st.DataObject) -> None:
    value = data.draw(mutated(data.draw(valid_data(topic), label="valid")), label="mutated")
    decode_all_ways(pack(envelope(schema_of(topic), value)), topic)


@pytest.mark.parametrize("topic", CASES, ids=IDS)
@FUZZ
@given(data=st.data())
def test_mutated_envelopes(topic: Topic[Any] | None, data: st.DataObject) -> None:
    env = data.draw(mutated_envelopes(topic), label="envelope")
    decode_all_ways(pack(env), topic)


@pytest.mark.parametrize("topic", CASES, ids=IDS)
def test_envelope_edges(topic: Topic[Any] | None) -> None:
    """Each envelope field at and beyond its limits, one at a time, on otherwise valid data:
    the ones within limits are accepted, the others refused."""
    data = example_data(topic)
    schema = schema_of(topic)
    ok = [{"v": 1}, {"stamp_ns": 0}, {"stamp_ns": INT64_MAX}, {"seq": INT64_MAX},
          {"period_s": 1e-6}, {"period_s": 3600}, {"pub": 1}, {"pub": INT64_MAX}]
    bad = [{"v": 2}, {"v": 0}, {"v": 2**64 - 1}, {"v": "1"}, {"stamp_ns": -1},
           {"stamp_ns": 2**63}, {"stamp_ns": 2**64 - 1}, {"stamp_ns": -2**63},
           {"stamp_ns": 1.0}, {"seq": -1}, {"seq": 2**64 - 1}, {"period_s": 0},
           {"period_s": math.nan}, {"period_s": math.inf}, {"period_s": -math.inf},
           {"pub": 0}, {"pub": 2**63}, {"pub": True}, {"schema": "x" * 65},
           {"unknown": 1}, {"data": [data]}, {"data": None}]
    for change in ok:
        payload = pack({**envelope(schema, data), **change})
        assert decode_all_ways(payload, topic), change
    for change in bad:
        payload = pack({**envelope(schema, data), **change})
        with pytest.raises(ProtocolError):
            decode(payload)
    for missing in ("schema", "v", "stamp_ns", "seq", "data"):
        payload = pack({k: v for k, v in envelope(schema, data).items() if k != missing})
        with pytest.raises(ProtocolError, match=missing):
            decode(payload)


def _deep(opener: bytes, levels: int, leaf: bytes = b"\xc0") -> bytes:
    return opener * levels + leaf


DEEP = {
    "arrays": _deep(b"\x91", 10_000),
    "maps": _deep(b"\x81\xa1k", 10_000),
    "mixed": _deep(b"\x91\x81\xa1k", 5_000),
    "unfinished": b"\x91" * 10_000,  # truncated on top of it
}


@pytest.mark.parametrize("topic", CASES, ids=IDS)
@pytest.mark.parametrize("deep", list(DEEP), ids=list(DEEP))
def test_nesting_10000_deep(topic: Topic[Any] | None, deep: str) -> None:
    """msgspec raises RecursionError (not a decode error) on deep nesting: as the payload,
    as the data, in every field, in an unknown field, in the envelope."""
    nested = DEEP[deep]
    schema = schema_of(topic)
    payloads = [nested, raw_envelope(schema, nested)]
    for name in [*field_names(topic), "unknown_field"]:
        payloads.append(raw_envelope(schema, b"\x81" + pack(name) + nested))
    head = pack(envelope(schema, {}))
    payloads.append(bytes([head[0] + 1]) + head[1:] + pack("extra") + nested)
    for payload in payloads:
        assert not decode_all_ways(payload, topic)


RAW_VALUES = {
    # msgpack no packer of ours would write, as raw bytes
    "float32 NaN": b"\xca\x7f\xc0\x00\x00",
    "float32 inf": b"\xca\x7f\x80\x00\x00",
    "float64 -inf": b"\xcb\xff\xf0\x00\x00\x00\x00\x00\x00",
    "float64 NaN payload": b"\xcb\x7f\xf8\x00\x00\x00\x00\x00\x01",
    "uint64 max": b"\xcf" + b"\xff" * 8,
    "int64 min": b"\xd3\x80" + b"\x00" * 7,
    "invalid utf-8": b"\xa2\xff\xfe",
    "utf-8 surrogate": b"\xa3\xed\xa0\x80",
    "bin for str": b"\xc4\x02ok",
    "ext -2": b"\xd4\xfe\x00",
    "timestamp of 3 bytes": b"\xc7\x03\xff\x00\x00\x00",
    "ext 32 MB announced": b"\xc9\x02\x00\x00\x00\x05",
    "str 4 GB announced": b"\xdb\xff\xff\xff\xff",
    "array 4 G items announced": b"\xdd\xff\xff\xff\xff",
    "map 4 G items announced": b"\xdf\xff\xff\xff\xff",
    "never used 0xc1": b"\xc1",
}


@pytest.mark.parametrize("topic", CASES, ids=IDS)
def test_raw_msgpack_oddities_in_every_field(topic: Topic[Any] | None) -> None:
    """Non-finite float32/float64, integer edges, bad UTF-8, extension types (negative codes
    are reserved: msgpack-python cannot even build them), lengths announced and not sent."""
    schema = schema_of(topic)
    valid = pack(example_data(topic))
    for raw in RAW_VALUES.values():
        decode_all_ways(raw_envelope(schema, raw), topic)
        for name in [*field_names(topic), "unknown_field"]:
            others = {k: v for k, v in example_data(topic).items() if k != name}
            body = b"".join(pack(k) + pack(v) for k, v in others.items())
            data = bytes([0x80 | (len(others) + 1)]) + body + pack(name) + raw
            decode_all_ways(raw_envelope(schema, data), topic)
        assert decode_all_ways(raw_envelope(schema, valid), topic)


@pytest.mark.parametrize("topic", CASES, ids=IDS)
def test_one_megabyte_strings_and_long_arrays(topic: Topic[Any] | None) -> None:
    schema = schema_of(topic)
    for name in [*field_names(topic), "unknown_field"]:
        for big in ("x" * ONE_MB, b"x" * ONE_MB, [0] * (ONE_MB // 4), {"k": "x" * ONE_MB}):
            with pytest.raises(ProtocolError, match="exceeds"):
                decode(pack(envelope(schema, {name: big})))
        for long_ in ("x" * (MAX_STR_LEN + 1), list(range(MAX_CONTAINER_LEN + 1))):
            decode_all_ways(pack(envelope(schema, {name: long_})), topic)


# ---------------------------------------------------------------------------------------------
# Encoding


@pytest.mark.parametrize("topic", CASES, ids=IDS)
@FUZZ
@given(data=st.data())
def test_encode_refuses_with_protocol_error_or_publishes_what_it_accepts(
        topic: Topic[Any] | None, data: st.DataObject) -> None:
    """encode() of mutated data (a map, or the message class built from it) with nasty
    envelope arguments: ProtocolError, or a payload this side itself accepts."""
    value = data.draw(valid_data(topic), label="valid")
    if data.draw(st.booleans()):
        value = data.draw(mutated(value), label="mutated")
    args = data.draw(st.fixed_dictionaries(
        {"stamp_ns": st.integers(0, INT64_MAX) | NASTY_STAMPS,
         "seq": st.integers(0, INT64_MAX) | NASTY_STAMPS},
        optional={"period_s": NASTY_PERIODS, "pub": NASTY_PUBS}), label="args")
    inputs: list[Any] = [value]
    if topic is not None and topic.type is not PlainData and isinstance(value, dict) and all(
            k in topic.fields for k in value):
        # Unchecked (Struct() validates nothing); a missing field or __post_init__ refusing
        # is the constructor's business, not the codec's.
        with contextlib.suppress(Exception):
            inputs.append(topic.type(**value))
    for item in inputs:
        for schema in (topic if topic is not None else GENERIC_SCHEMA, schema_of(topic)):
            try:
                payload = encode(schema, item, **args)
            except ProtocolError as exc:
                assert str(exc)
                continue
            check_published(payload, schema_of(topic), item)


def check_published(payload: bytes, schema: str, item: Any) -> None:
    """What ``encode`` returned: accepted by ``decode`` (never publish what you would
    refuse), with the data given."""
    message = decode(payload, schema=schema)
    check_accepted(message, payload)
    kind = type_of(topics.BY_SCHEMA.get(schema))
    if kind is PlainData or isinstance(item, msgspec.Struct):
        expected = msgspec.convert(wire(item), kind)
    else:  # a map of fields: converted as encode did (an int in a float field is a float)
        expected = msgspec.convert(item, kind)
    assert message.data == expected


def wire(value: Any) -> Any:
    """``value`` as the wire carries it (arrays as lists, no defaults)."""
    return msgspec.msgpack.decode(msgspec.msgpack.encode(value))


NASTY_OBJECTS: list[Any] = [
    2**64, -2**63 - 1, 2**100, -2**100, math.nan, math.inf, object(), {1, 2}, 1j,
    "\ud800", "x" * ONE_MB, [0] * 5000, bytearray(b"x"), memoryview(b"x"),
]


def _self_referencing() -> list[Any]:
    loop: list[Any] = []
    loop.append(loop)
    return loop


def _nested(levels: int) -> Any:
    value: Any = None
    for _ in range(levels):
        value = [value]
    return value


@pytest.mark.parametrize("topic", CASES, ids=IDS)
def test_encode_of_python_objects_no_wire_can_carry(topic: Topic[Any] | None) -> None:
    """Integers beyond uint64, sets, objects, lone surrogates, self-referencing and
    10 000-deep lists: in a map of fields, and in a message class built unchecked."""
    schema = topic if topic is not None else GENERIC_SCHEMA
    valid = example_data(topic)
    for name in field_names(topic):
        for bad in [*NASTY_OBJECTS, _self_referencing(), _nested(10_000),
                    {"children": _nested(10_000)}]:
            values: list[Any] = [{**valid, name: bad}]
            if topic is not None and topic.type is not PlainData:
                with contextlib.suppress(Exception):  # unchecked but for __post_init__
                    values.append(msgspec.structs.replace(msgspec.convert(valid, topic.type),
                                                          **{name: bad}))
            for value in values:
                try:
                    payload = encode(schema, value, stamp_ns=1, seq=1)
                except ProtocolError as exc:
                    assert str(exc)
                    continue
                check_published(payload, schema_of(topic), value)




@pytest.mark.parametrize("stamp_ns,seq,period_s,pub", [
    (-1, 1, None, None), (2**63, 1, None, None), (2**100, 1, None, None), (1.0, 1, None, None),
    (1, -1, None, None), (1, 2**64, None, None), (1, True, None, None),
    (1, 1, "0.05", None), (1, 1, math.nan, None), (1, 1, 0.0, None), (1, 1, [0.05], None),
    (1, 1, 1j, None), (1, 1, True, None),
    (1, 1, None, 0), (1, 1, None, 2**63), (1, 1, None, "7"), (1, 1, None, True),
])
def test_encode_refuses_envelope_values_with_protocol_error(
        stamp_ns: Any, seq: Any, period_s: Any, pub: Any) -> None:
    with pytest.raises(ProtocolError):
        encode(topics.LEDS, {"mask": 1}, stamp_ns=stamp_ns, seq=seq, period_s=period_s, pub=pub)


@pytest.mark.parametrize("schema", ["x" * 65, 7, None, ["leds"], b"leds"])
def test_encode_refuses_a_schema_name_decode_would_refuse(schema: Any) -> None:
    """Regression: a schema name over 64 characters was encoded and then refused by every
    receiver (this side included); a non-string one raised TypeError."""
    with pytest.raises(ProtocolError, match="schema"):
        encode(schema, {"x": 1}, stamp_ns=1, seq=1)


def test_encode_refuses_a_payload_over_the_size_limit() -> None:
    """Regression: encode accepted data whose payload every receiver refuses as too large
    (each string within its limit, many of them)."""
    data = {str(i): "x" * MAX_STR_LEN for i in range(MAX_PAYLOAD_BYTES // MAX_STR_LEN + 1)}
    with pytest.raises(ProtocolError, match="exceeds"):
        encode(GENERIC_SCHEMA, data, stamp_ns=1, seq=1)
    slots = [topics.TreeSlot(composite="c" * 128, name="n" * 128, priority=0, weight=1.0)] * 4096
    with pytest.raises(ProtocolError, match="exceeds"):
        encode(topics.TREE_REPLY, topics.TreeReply(ok=False, error="e", slots=tuple(slots)),
               stamp_ns=1, seq=1)


def test_encode_of_out_of_range_python_ints_in_a_message_class() -> None:
    """Regression: an int msgpack cannot carry (beyond uint64) in a message built unchecked
    raised OverflowError, and a self-referencing list RecursionError, out of encode."""
    with pytest.raises(ProtocolError):
        encode(topics.LEDS, topics.Leds(mask=2**64), stamp_ns=1, seq=1)
    with pytest.raises(ProtocolError):
        encode(topics.DRIVE, topics.Drive(speed=0.0, turn=0.0, winners=_self_referencing()),
               stamp_ns=1, seq=1)


# ---------------------------------------------------------------------------------------------
# A plain msgpack client, as docs/protocol.md describes one

VALID_EXAMPLES: dict[str, tuple[str, dict[str, Any]]] = {
    # sensor kind: (schema, data) as the tables of docs/protocol.md describe it
    "camera": ("camera.seekcolor", {"bins": [0, 12, 340, 5, 0], "total": 357,
                                    "bearing_rad": 0.02, "latency_s": 0.011, "width": 160,
                                    "height": 120}),
    "range": ("range", {"range_mm": 250, "status": "ok"}),
    "encoders": ("encoders", {"left_edges": 1200, "right_edges": -3, "left_counts": 300.5,
                              "right_counts": 0, "errors": 0, "mode": "phase"}),
    "odometry": ("odometry", {"x_m": 1.25, "y_m": -0.5, "heading_rad": 3.14159}),
    "motors": ("motors.applied", {"speed": 40, "turn": -10.5, "left_ms": 1.7,
                                  "right_ms": 1.3, "left_dir": 1, "right_dir": -1,
                                  "reason": "command"}),
    "radio": ("radio.message", {"text": "hello"}),
    "leds": ("leds.state", {"mask": 1, "count": 2}),
}

def test_every_sensor_topic_has_a_plain_client_example() -> None:
    assert set(VALID_EXAMPLES) == set(topics.SENSORS), "add an example from docs/protocol.md"


@pytest.mark.parametrize("kind", sorted(VALID_EXAMPLES))
def test_a_plain_msgpack_client_payload_decodes(kind: str) -> None:
    """The envelope exactly as docs/protocol.md's plain-Python sensor builds it, with each
    sensor kind's data from the schema tables; the minimal form (optional fields left out)
    too."""
    schema, data = VALID_EXAMPLES[kind]
    topic = topics.SENSORS[kind]
    assert topic.schema == schema
    payload = msgpack.packb({"schema": schema, "v": 1, "stamp_ns": 123_456_789, "seq": 7,
                             "period_s": 0.05, "data": data})
    message = decode(payload, topic=topic)
    assert isinstance(message.data, topic.type)
    assert message.data == msgspec.convert(data, topic.type)
    as_sent = wire(message.data)
    assert {k: as_sent.get(k, getattr(message.data, k)) for k in data} == data
    assert (message.stamp_ns, message.seq, message.period_s, message.pub) == (
        123_456_789, 7, 0.05, None)
    check_accepted(message, payload)
    required = {f.encode_name for f in mi.type_info(topic.type).fields if f.required}
    minimal = {k: v for k, v in data.items() if k in required}
    assert decode(msgpack.packb(envelope(schema, minimal)), topic=topic).data == \
        msgspec.convert(minimal, topic.type)
