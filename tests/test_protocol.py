"""The codec treats every payload as untrusted and raises ProtocolError, and nothing else."""

from __future__ import annotations

import math

import msgpack
import pytest

from ubf_async.errors import ProtocolError
from ubf_async.wire.keys import Keys
from ubf_async.wire.protocol import MAX_PAYLOAD_BYTES, Encoder, decode, encode
from ubf_async.wire.topics import DRIVE, BasedOn, Drive, Range


def envelope(data: object, **overrides: object) -> bytes:
    env = {"schema": "range", "v": 1, "stamp_ns": 10, "seq": 1, "data": data}
    env.update(overrides)
    return msgpack.packb(env)


GOOD_RANGE = {"range_mm": 420, "status": "ok"}


def test_round_trip() -> None:
    payload = encode("range", GOOD_RANGE, stamp_ns=123, seq=4, period_s=0.05)
    msg = decode(payload)
    assert (msg.schema, msg.stamp_ns, msg.seq, msg.period_s) == ("range", 123, 4, 0.05)
    assert msg.data == Range(range_mm=420, status="ok")
    assert msg.data.range_mm == 420
    assert msgpack.unpackb(payload)["data"] == GOOD_RANGE  # defaults stay off the wire


def test_unknown_schema_accepted_with_generic_checks() -> None:
    msg = decode(envelope({"lux": 12.5, "tags": ["a", 1]}, schema="light"))
    assert msg.data == {"lux": 12.5, "tags": ["a", 1]}
    with pytest.raises(ProtocolError, match="not finite"):
        decode(envelope({"lux": math.nan}, schema="light"))


BAD_PAYLOADS = {
    "garbage": b"\xc1\xff\x00garbage",
    "empty": b"",
    "truncated": envelope(GOOD_RANGE)[:-3],
    "trailing bytes": envelope(GOOD_RANGE) + b"\x00",
    "not a map": msgpack.packb([1, 2, 3]),
    "int map keys": msgpack.packb({1: "x"}),
    "missing stamp": msgpack.packb({"schema": "range", "v": 1, "seq": 1, "data": GOOD_RANGE}),
    "negative stamp": envelope(GOOD_RANGE, stamp_ns=-5),
    "stamp is str": envelope(GOOD_RANGE, stamp_ns="now"),
    "bool seq": envelope(GOOD_RANGE, seq=True),
    "future version": envelope(GOOD_RANGE, v=2),
    "unexpected envelope field": envelope(GOOD_RANGE, extra=1),
    "data not a map": envelope([1, 2]),
    "missing field": envelope({"status": "ok"}),
    "wrong type": envelope({"range_mm": "far", "status": "ok"}),
    "float for int": envelope({"range_mm": 4.2, "status": "ok"}),
    "out of range": envelope({"range_mm": -1, "status": "ok"}),
    "bad choice": envelope({"range_mm": 1, "status": "great"}),
    "nan period": envelope(GOOD_RANGE, period_s=math.nan),
    "inf in drive": envelope({"speed": math.inf, "turn": 0}, schema="drive"),
    "nan in drive": envelope({"speed": 0.0, "turn": math.nan}, schema="drive"),
    "drive over 100": envelope({"speed": 100.5, "turn": 0}, schema="drive"),
    "bad utf8": b"\x81\xa6schema\xa2\xff\xfe",
    "deep nesting": envelope({"x": [[[[[[[[[[[[1]]]]]]]]]]]]}, schema="custom"),
    "ext type": msgpack.packb(msgpack.ExtType(5, b"abc")),
    "huge": b"\x00" * (MAX_PAYLOAD_BYTES + 1),
    "very deep raw": b"\x91" * 100_000 + b"\x00",
}


@pytest.mark.parametrize("name", list(BAD_PAYLOADS))
def test_bad_payloads_raise_protocol_error_only(name: str) -> None:
    with pytest.raises(ProtocolError):
        decode(BAD_PAYLOADS[name])


def test_generic_data_bounds_map_keys_and_schemas_are_named() -> None:
    with pytest.raises(ProtocolError, match="map key"):
        decode(envelope({"k" * 129: 1}, schema="light"))
    assert decode(envelope({"k" * 128: 1}, schema="light")).data == {"k" * 128: 1}
    with pytest.raises(ProtocolError, match="schema"):
        decode(envelope({"lux": 1.0}, schema=""))
    with pytest.raises(ProtocolError, match="schema"):
        encode("", {"lux": 1.0}, stamp_ns=1, seq=1)


def test_schema_required_by_key() -> None:
    with pytest.raises(ProtocolError, match="expected 'drive'"):
        decode(envelope(GOOD_RANGE), schema="drive")


def test_encode_refuses_what_decode_would_reject() -> None:
    with pytest.raises(ProtocolError):
        encode("drive", {"speed": math.nan, "turn": 0}, stamp_ns=0, seq=1)
    with pytest.raises(ProtocolError):
        encode("range", GOOD_RANGE, stamp_ns=-1, seq=1)


def test_a_trusted_encoder_sends_the_same_bytes_and_still_checks_what_it_is_not_told() -> None:
    drive = Drive(speed=-50.0, turn=0.0, tick=7, winners=("avoid",), ticked_by="event",
                  based_on=BasedOn(source="range/front", seq=3, stamp_ns=99))
    trusted = Encoder(DRIVE, period_s=0.02, pub=5, trusted=True)
    payload = trusted.encode(drive, stamp_ns=123, seq=4)
    assert payload == encode(DRIVE, drive, stamp_ns=123, seq=4, period_s=0.02, pub=5)
    message = decode(payload, topic=DRIVE)
    assert (message.data, message.stamp_ns, message.seq, message.period_s, message.pub) == (
        drive, 123, 4, 0.02, 5)
    # Built valid is the caller's promise for the typed message only: a map is still checked,
    # and so are the stamp and the number of every message.
    with pytest.raises(ProtocolError):
        trusted.encode({"speed": 500.0, "turn": 0.0}, stamp_ns=1, seq=1)
    with pytest.raises(ProtocolError):
        trusted.encode(drive, stamp_ns=-1, seq=1)
    with pytest.raises(ProtocolError):
        trusted.encode(drive, stamp_ns=1, seq=True)
    # Untrusted (every other publisher): the typed message is validated as a receiver will.
    with pytest.raises(ProtocolError):
        Encoder(DRIVE).encode(Drive(speed=500.0, turn=0.0), stamp_ns=1, seq=1)
    with pytest.raises(ProtocolError):
        Encoder(DRIVE, pub=0)
    with pytest.raises(ProtocolError):
        Encoder(DRIVE, period_s=0.0)


def test_keys() -> None:
    keys = Keys("mini")
    assert keys.sensor("camera", "front") == "ubf/mini/sensor/camera/front"
    assert keys.source_of("ubf/mini/sensor/camera/front") == "camera/front"
    assert keys.cmd("drive") == "ubf/mini/cmd/drive"
    assert keys.alive("motors") == "ubf/mini/alive/motors"
    with pytest.raises(ProtocolError):
        keys.source_of("ubf/other/sensor/camera/front")
    with pytest.raises(ProtocolError):
        keys.sensor("camera", "a/b")
    with pytest.raises(ProtocolError):
        Keys("bad*robot")
