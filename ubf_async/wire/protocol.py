"""The wire protocol's codec: msgpack envelopes (version 1).

Everything another process needs to attach to a robot is here, in :mod:`ubf_async.wire.keys`
(the key expressions) and :mod:`ubf_async.wire.topics` (each topic's message), and in
``docs/protocol.md``; these modules are its executable form. Pure functions, no I/O: the bus
moves bytes, this module turns them into validated messages and back.

Every payload is a msgpack map (the *envelope*)::

    {"schema": "range", "v": 1, "stamp_ns": 1234, "seq": 7, "period_s": 0.05,
     "pub": 81985529216486895, "data": {...}}

(``period_s`` and ``pub`` are optional.)

What each schema's ``data`` holds is declared once, with its constraints, in
:mod:`ubf_async.wire.topics`; this module decodes and encodes through those types with msgspec.
Decoding treats every payload as untrusted: a size limit, every decoder error caught, types,
ranges, lengths and finiteness checked, nesting bounded. Whatever is wrong, the only
exception that escapes is :class:`ProtocolError`. Data of a schema not declared there (a
new kind of sensor) is checked generically (:func:`plain`).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Annotated, Any, Generic, TypeVar, overload

import msgspec
from msgspec import Meta

from ubf_async import throttle
from ubf_async.errors import ProtocolError
from ubf_async.wire.topics import (
    BY_SCHEMA,
    INT64_MAX,
    MAX_NAME_CHARS,
    PlainData,
    StampNs,
    Topic,
    plain,
)

__all__ = ["MAX_PAYLOAD_BYTES", "PROTOCOL_VERSION", "Encoder", "Message", "clip",
           "count_malformed", "decode", "encode"]

PROTOCOL_VERSION = 1
MAX_PAYLOAD_BYTES = 256 * 1024


def clip(value: str, max_len: int = MAX_NAME_CHARS) -> str:
    """``value`` cut to ``max_len`` characters (the last one an ellipsis when cut): for names
    copied into outgoing messages, which must never fail their own validation."""
    return value if len(value) <= max_len else value[: max_len - 1] + "…"



# ---------------------------------------------------------------------------------------------
# The envelope and the codec

T = TypeVar("T")


class Message(msgspec.Struct, Generic[T], frozen=True, kw_only=True, gc=False):
    """A decoded, validated payload. ``data`` is the topic's typed message
    (:mod:`ubf_async.wire.topics`), or a plain map for a schema not declared there. (A msgspec
    Struct rather than a dataclass: it is made for every sample, and is cheaper to make.)"""

    schema: str
    stamp_ns: int
    seq: int
    data: T
    period_s: float | None = None
    version: int = PROTOCOL_VERSION
    pub: int | None = None
    """The publisher's identity (random, new for every publisher instance) or ``None`` for a
    client that does not send one; see :mod:`ubf_async.runtime.ordering`."""


PublisherId = Annotated[int, Meta(ge=1, le=INT64_MAX)]


MAX_SCHEMA_CHARS = 64


class _Envelope(msgspec.Struct, forbid_unknown_fields=True, omit_defaults=True):
    schema: Annotated[str, Meta(min_length=1, max_length=MAX_SCHEMA_CHARS)]
    v: Annotated[int, Meta(ge=1, le=1000)]
    stamp_ns: StampNs
    seq: Annotated[int, Meta(ge=0, le=INT64_MAX)]
    data: msgspec.Raw
    period_s: Annotated[float, Meta(ge=1e-6, le=3600.0)] | None = None
    pub: PublisherId | None = None


_ENVELOPE = msgspec.msgpack.Decoder(_Envelope)
_ENCODER = msgspec.msgpack.Encoder()
_DECODERS: dict[str, msgspec.msgpack.Decoder[Any]] = {
    schema: msgspec.msgpack.Decoder(topic.type)
    for schema, topic in BY_SCHEMA.items() if topic.type is not PlainData
}
_GENERIC = msgspec.msgpack.Decoder()


def _where(exc: Exception, part: str) -> str:
    """msgspec's message with its ``$`` path named after the part decoded."""
    return str(exc).replace("`$`", f"`{part}`").replace("`$.", f"`{part}.")


def decode_data(schema: str, raw: bytes | memoryview | msgspec.Raw) -> Any:
    """Decode and validate the ``data`` of ``schema`` from its msgpack bytes (raises
    :class:`ProtocolError` and nothing else)."""
    decoder = _DECODERS.get(schema)
    try:
        if decoder is not None:
            return decoder.decode(raw)
        data = _GENERIC.decode(raw)
    except msgspec.MsgspecError as exc:
        raise ProtocolError(f"{schema} data: {_where(exc, 'data')}") from None
    except RecursionError:
        raise ProtocolError("data nested too deeply") from None
    except (ValueError, TypeError) as exc:  # raised by a type's own checks
        raise ProtocolError(f"{schema} data: {exc}") from None
    if not isinstance(data, dict):
        raise ProtocolError(f"data: expected a map, got {type(data).__name__}")
    return plain(data)


@overload
def decode(payload: bytes | bytearray | memoryview, *, topic: Topic[T]) -> Message[T]: ...
@overload
def decode(payload: bytes | bytearray | memoryview, *,
           schema: str | None = None) -> Message[Any]: ...
def decode(payload: bytes | bytearray | memoryview, *, schema: str | None = None,
           topic: Topic[Any] | None = None) -> Message[Any]:
    """Decode an untrusted payload. Raises :class:`ProtocolError` and nothing else.

    ``topic`` (or ``schema``), when given, is what the key requires: a drive key only accepts
    ``"drive"``, so ``decode(p, topic=DRIVE).data`` is a :class:`~ubf_async.wire.topics.Drive`.
    """
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise ProtocolError(f"payload of {len(payload)} bytes exceeds {MAX_PAYLOAD_BYTES}")
    try:
        envelope = _ENVELOPE.decode(payload)
    except msgspec.MsgspecError as exc:
        raise ProtocolError(f"envelope: {_where(exc, 'envelope')}") from None
    except RecursionError:
        raise ProtocolError("payload nested too deeply") from None
    except (ValueError, TypeError) as exc:  # e.g. a string that is not UTF-8
        raise ProtocolError(f"envelope: {exc}") from None
    if envelope.v != PROTOCOL_VERSION:
        raise ProtocolError(f"envelope.v: version {envelope.v} unsupported "
                            f"(this side speaks {PROTOCOL_VERSION})")
    expected = topic.schema if topic is not None else schema
    if expected is not None and envelope.schema != expected:
        raise ProtocolError(f"envelope.schema: expected {expected!r}, got {envelope.schema!r}")
    return Message(
        schema=envelope.schema,
        stamp_ns=envelope.stamp_ns,
        seq=envelope.seq,
        data=decode_data(envelope.schema, envelope.data),
        period_s=envelope.period_s,
        pub=envelope.pub,
    )


def encode_data(schema: str, data: Any) -> bytes:
    """The msgpack bytes of ``data`` for ``schema``, validated exactly as a receiver will:
    ``data`` is the topic's message (or a map of its fields; a plain map for a schema not
    declared in :mod:`ubf_async.wire.topics`). Raises :class:`ProtocolError`."""
    topic = BY_SCHEMA.get(schema)
    kind = topic.type if topic is not None else PlainData
    try:
        if kind is PlainData:
            if not isinstance(data, Mapping):
                raise ProtocolError(f"{schema} data: expected a map, got {type(data).__name__}")
            return _ENCODER.encode(plain(dict(data)))
        if isinstance(data, kind):
            raw = _ENCODER.encode(data)
            _DECODERS[schema].decode(raw)  # the constraints, as the receiver checks them
            return raw
        if isinstance(data, Mapping):
            return _ENCODER.encode(msgspec.convert(dict(data), kind))
    except msgspec.MsgspecError as exc:
        raise ProtocolError(f"{schema} data: {_where(exc, 'data')}") from None
    except RecursionError:
        raise ProtocolError(f"{schema} data: nested too deeply") from None
    except (ValueError, TypeError, OverflowError) as exc:  # OverflowError: an int beyond uint64
        raise ProtocolError(f"{schema} data: {exc}") from None
    raise ProtocolError(f"{schema} data: expected {kind.__name__} or a map of its fields, "
                        f"got {type(data).__name__}")


def encode(
    schema: str | Topic[Any],
    data: Any,
    *,
    stamp_ns: int,
    seq: int,
    period_s: float | None = None,
    pub: int | None = None,
) -> bytes:
    """Build a payload of ``schema`` (a name or a :class:`~ubf_async.wire.topics.Topic`). The data
    is validated like incoming data, so this side never publishes what it would itself
    reject (raises :class:`ProtocolError`). ``pub`` is the publisher's identity
    (:class:`~ubf_async.runtime.bus.Publisher` sets it). A publisher keeps an
    :class:`Encoder` instead, which checks what does not change once."""
    return Encoder(schema, period_s=period_s, pub=pub).encode(data, stamp_ns=stamp_ns, seq=seq)


def encode_raw(schema: str, raw: bytes, *, stamp_ns: int, seq: int,
               period_s: float | None = None, pub: int | None = None) -> bytes:
    """An envelope around data already encoded and validated by :func:`encode_data`."""
    return Encoder(schema, period_s=period_s, pub=pub).wrap(msgspec.Raw(raw), stamp_ns=stamp_ns,
                                                            seq=seq)


class _Outgoing(msgspec.Struct, omit_defaults=True):
    """The envelope as it is sent: :class:`_Envelope`'s fields in its order, ``data`` either
    the topic's message itself (encoded inline, one pass) or bytes already encoded."""

    schema: str
    v: int
    stamp_ns: int
    seq: int
    data: Any
    period_s: float | None = None
    pub: int | None = None


def _check_count(name: str, value: object, low: int = 0) -> None:
    if value.__class__ is not int and (isinstance(value, bool) or not isinstance(value, int)):
        raise ProtocolError(f"{name}: {value!r} is not an integer in [{low}, 2**63-1]")
    if not low <= value <= INT64_MAX:
        raise ProtocolError(f"{name}: {value!r} is not an integer in [{low}, 2**63-1]")


class Encoder:
    """Encodes the messages of one publisher: the schema, ``period_s`` and the publisher
    identity ``pub`` are checked once, here; each :meth:`encode` checks ``stamp_ns`` and
    ``seq`` and validates the data as a receiver will (:func:`encode_data`).

    ``trusted``: the caller builds its data valid by construction as the topic's typed message
    (the controller's drive command: speed and turn from a validated
    :class:`~ubf_async.core.action.Action`, names clipped, counts from validated samples), so
    its constraints are not checked again on every message and the envelope is encoded in one
    pass with the data inline. A map, or another type, is still converted and checked."""

    __slots__ = ("_kind", "_period_s", "_pub", "_trusted", "schema")

    def __init__(self, schema: str | Topic[Any], *, period_s: float | None = None,
                 pub: int | None = None, trusted: bool = False) -> None:
        self.schema = schema.schema if isinstance(schema, Topic) else _check_schema(schema)
        if pub is not None:
            _check_count("pub", pub, 1)
        if period_s is not None and (isinstance(period_s, bool)
                                     or not isinstance(period_s, int | float)
                                     or not 1e-6 <= period_s <= 3600.0):
            raise ProtocolError(f"period_s: {period_s!r} is not a number in [1e-6, 3600]")
        self._period_s = None if period_s is None else float(period_s)
        self._pub = pub
        topic = BY_SCHEMA.get(self.schema)
        self._kind: type | None = topic.type if topic is not None and trusted else None
        self._trusted = trusted

    def encode(self, data: Any, *, stamp_ns: int, seq: int) -> bytes:
        """The payload of ``data`` stamped ``stamp_ns``, numbered ``seq`` (raises
        :class:`ProtocolError`)."""
        if self._kind is not None and data.__class__ is self._kind:
            return self.wrap(data, stamp_ns=stamp_ns, seq=seq)
        return self.wrap(msgspec.Raw(encode_data(self.schema, data)), stamp_ns=stamp_ns, seq=seq)

    def wrap(self, data: Any, *, stamp_ns: int, seq: int) -> bytes:
        """The envelope around ``data``: a valid message, or its bytes (``msgspec.Raw``)."""
        _check_count("stamp_ns", stamp_ns)
        _check_count("seq", seq)
        payload = _ENCODER.encode(_Outgoing(self.schema, PROTOCOL_VERSION, stamp_ns, seq, data,
                                            self._period_s, self._pub))
        if len(payload) > MAX_PAYLOAD_BYTES:
            raise ProtocolError(f"payload of {len(payload)} bytes exceeds {MAX_PAYLOAD_BYTES}")
        return payload


def _check_schema(schema: object) -> str:
    """``schema`` if it is a name receivers accept in an envelope."""
    if not isinstance(schema, str) or not 0 < len(schema) <= MAX_SCHEMA_CHARS:
        raise ProtocolError(f"schema: {schema!r:.80} is not a string of 1 to "
                            f"{MAX_SCHEMA_CHARS} characters")
    return schema


# -- decoding what arrives, counting what is refused --------------------------------------------

log = logging.getLogger(__name__)

MAX_COUNTED_KEYS = 1024
"""Keys whose malformed-sample counts :func:`count_malformed` keeps (the oldest goes first)."""


def decode_or_count(
    payload: bytes, counter: dict[str, int], key: str, *, schema: str | None = None,
    topic: Topic[Any] | None = None,
) -> Any | None:
    """Decode ``payload`` (requiring ``topic``'s schema, or ``schema``, if given); on
    :class:`ProtocolError` count it under ``key`` (:func:`count_malformed`) and return
    ``None``. (A subscriber of a topic wants ``Bus.subscribe_topic``, which decodes before
    anything can displace a valid sample.)"""
    try:
        return decode(payload, topic=topic) if topic is not None else decode(payload,
                                                                             schema=schema)
    except ProtocolError as exc:
        count_malformed(counter, key, exc)
        return None


def count_malformed(counter: dict[str, int], key: str, error: ProtocolError, n: int = 1) -> None:
    """Count ``n`` malformed samples on ``key`` (the last of them refused for ``error``) and log
    it, the first and then every 100th per key. ``counter`` keeps at most
    :data:`MAX_COUNTED_KEYS` keys, so junk keys cannot grow it without bound."""
    before = counter.get(key, 0)
    counter[key] = after = before + n
    if len(counter) > MAX_COUNTED_KEYS:
        del counter[next(iter(counter))]
    if throttle.passes(before, after):
        log.warning("rejected malformed sample #%d on %s: %s", after, key, error)
