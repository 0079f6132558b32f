"""The wire protocol: key expressions and the msgpack codec (version 1).

Everything another process needs to attach to a robot is here and in ``docs/protocol.md``;
this module is its executable form. Pure functions, no zenoh: the bus module moves bytes,
this one turns them into validated messages and back.

Every payload is a msgpack map (the *envelope*)::

    {"schema": "range", "v": 1, "stamp_ns": 1234, "seq": 7, "period_s": 0.05,
     "pub": 81985529216486895, "data": {...}}

(``period_s`` and ``pub`` are optional.)

Decoding treats every payload as untrusted: size limits, ``strict_map_key``, every
unpacker error caught, types, ranges and finiteness checked. Whatever is wrong, the only
exception that escapes is :class:`ProtocolError`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import msgpack

# Defined with the rest of the exception tree; re-exported here, where it has always been.
from ubf_async.errors import ProtocolError as ProtocolError

PROTOCOL_VERSION = 1
ROOT = "ubf"
MAX_PAYLOAD_BYTES = 256 * 1024
MAX_STR_LEN = 4096
MAX_CONTAINER_LEN = 4096
MAX_DEPTH = 8
INT64_MAX = 2**63 - 1
MAX_NAME_CHARS = 128
"""Longest name a command or status carries back out: a state source (``"<kind>/<name>"``)
in ``based_on.source``, a behaviour in ``winners``. The aggregator refuses sources with
longer names, so whatever the controller copies from its input stays publishable."""


# ---------------------------------------------------------------------------------------------
# Key expressions


def _check_segment(what: str, value: str) -> str:
    if not value or any(c in value for c in "/*$?#") or value != value.strip():
        raise ProtocolError(f"{what} {value!r} must be one non-empty key segment without / * $ ? #")
    return value


@dataclass(frozen=True, slots=True)
class Keys:
    """The key expressions of one robot, ``ubf/<robot>/...``."""

    robot: str

    def __post_init__(self) -> None:
        _check_segment("robot name", self.robot)

    @property
    def prefix(self) -> str:
        return f"{ROOT}/{self.robot}"

    def sensor(self, kind: str, name: str) -> str:
        """Where a sensor publishes its samples; its state source is ``"<kind>/<name>"``."""
        return f"{self.prefix}/sensor/{_check_segment('kind', kind)}/{_check_segment('name', name)}"

    def sensors_of_kind(self, kind: str) -> str:
        return f"{self.prefix}/sensor/{_check_segment('kind', kind)}/*"

    @property
    def all_sensors(self) -> str:
        return f"{self.prefix}/sensor/*/*"

    def source_of(self, key: str) -> str:
        """``ubf/<robot>/sensor/<kind>/<name>`` → ``"<kind>/<name>"``."""
        head = f"{self.prefix}/sensor/"
        if not key.startswith(head) or key.count("/") != head.count("/") + 1:
            raise ProtocolError(f"{key!r} is not a sensor key of robot {self.robot!r}")
        return key[len(head):]

    def cmd(self, target: str) -> str:
        """Commands: ``drive``, ``seek_color``, ``radio``, ``leds``."""
        return f"{self.prefix}/cmd/{_check_segment('command target', target)}"

    def alive(self, component: str) -> str:
        """A component's liveliness token."""
        return f"{self.prefix}/alive/{_check_segment('component name', component)}"

    @property
    def all_alive(self) -> str:
        return f"{self.prefix}/alive/*"

    def component_of_alive(self, key: str) -> str:
        return key.rsplit("/", 1)[-1]

    def heartbeat(self, component: str) -> str:
        return f"{self.prefix}/heartbeat/{_check_segment('component name', component)}"

    @property
    def all_heartbeats(self) -> str:
        return f"{self.prefix}/heartbeat/*"

    @property
    def clock(self) -> str:
        """Simulation time, published by a simulator (absent in wall-clock runs)."""
        return f"{self.prefix}/clock"

    def sim(self, topic: str) -> str:
        """A simulator's own topics, outside ``sensor/`` so behaviours never see them:
        ``truth`` (robot and ball poses), ``world`` (the full snapshot, for sim-backed devices
        in other processes) and ``pulses`` (motor pulses from such a motors process)."""
        return f"{self.prefix}/sim/{_check_segment('sim topic', topic)}"

    def status(self, component: str) -> str:
        return f"{self.prefix}/status/{_check_segment('component name', component)}"

    @property
    def tree(self) -> str:
        """The robot's live-tree queryable (:mod:`ubf_async.live`)."""
        return f"{self.prefix}/tree"

    @property
    def everything(self) -> str:
        return f"{self.prefix}/**"


# ---------------------------------------------------------------------------------------------
# Field validators: small composable checks. Each returns the (possibly normalised) value or
# raises ProtocolError naming the field.

Check = Callable[[Any, str], Any]


def boolean(value: Any, path: str) -> bool:
    if not isinstance(value, bool):
        raise ProtocolError(f"{path}: expected a boolean, got {type(value).__name__}")
    return value


def integer(lo: int = -INT64_MAX, hi: int = INT64_MAX, *, nullable: bool = False) -> Check:
    def check(value: Any, path: str) -> Any:
        if value is None and nullable:
            return None
        if isinstance(value, bool) or not isinstance(value, int):
            raise ProtocolError(f"{path}: expected an integer, got {type(value).__name__}")
        if not lo <= value <= hi:
            raise ProtocolError(f"{path}: {value} outside [{lo}, {hi}]")
        return value

    return check


def number(lo: float = -math.inf, hi: float = math.inf, *, nullable: bool = False) -> Check:
    """A finite int or float within [lo, hi] (NaN and infinities are always refused)."""

    def check(value: Any, path: str) -> Any:
        if value is None and nullable:
            return None
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ProtocolError(f"{path}: expected a number, got {type(value).__name__}")
        if not math.isfinite(value):
            raise ProtocolError(f"{path}: {value} is not finite")
        if not lo <= value <= hi:
            raise ProtocolError(f"{path}: {value} outside [{lo}, {hi}]")
        return float(value)

    return check


def text(max_len: int = MAX_STR_LEN, *, choices: tuple[str, ...] = (),
         nullable: bool = False) -> Check:
    def check(value: Any, path: str) -> Any:
        if value is None and nullable:
            return None
        if not isinstance(value, str):
            raise ProtocolError(f"{path}: expected a string, got {type(value).__name__}")
        if len(value) > max_len:
            raise ProtocolError(f"{path}: string longer than {max_len}")
        if choices and value not in choices:
            raise ProtocolError(f"{path}: {value!r} not one of {list(choices)}")
        return value

    return check


def array(item: Check, *, min_len: int = 0, max_len: int = MAX_CONTAINER_LEN,
          nullable: bool = False) -> Check:
    def check(value: Any, path: str) -> Any:
        if value is None and nullable:
            return None
        if not isinstance(value, list | tuple):
            raise ProtocolError(f"{path}: expected an array, got {type(value).__name__}")
        if not min_len <= len(value) <= max_len:
            raise ProtocolError(f"{path}: array length {len(value)} outside [{min_len}, {max_len}]")
        return [item(v, f"{path}[{i}]") for i, v in enumerate(value)]

    return check


def record(fields: Mapping[str, Check], *, optional: tuple[str, ...] = (),
           nullable: bool = False, extra: bool = True) -> Check:
    """A map with the given fields. Fields in ``optional`` may be absent; unknown extra fields
    are kept after a generic check when ``extra`` is true (forward compatibility)."""

    def check(value: Any, path: str) -> Any:
        if value is None and nullable:
            return None
        if not isinstance(value, dict):
            raise ProtocolError(f"{path}: expected a map, got {type(value).__name__}")
        out: dict[str, Any] = {}
        for name, field_check in fields.items():
            if name in value:
                out[name] = field_check(value[name], f"{path}.{name}")
            elif name not in optional:
                raise ProtocolError(f"{path}: missing field {name!r}")
        for name, v in value.items():
            if name not in fields:
                if not extra:
                    raise ProtocolError(f"{path}: unexpected field {name!r}")
                out[name] = plain(v, f"{path}.{name}")
        return out

    return check


def plain(value: Any, path: str, depth: int = 0) -> Any:
    """Generic check for data of unknown schemas: nil, bool, int64, finite float, str,
    bytes, arrays and str-keyed maps, nested at most ``MAX_DEPTH`` deep."""
    if depth > MAX_DEPTH:
        raise ProtocolError(f"{path}: nested deeper than {MAX_DEPTH}")
    if value is None or isinstance(value, bool | str | bytes):
        return value
    if isinstance(value, int):
        return integer()(value, path)
    if isinstance(value, float):
        return number()(value, path)
    if isinstance(value, list | tuple):
        return [plain(v, f"{path}[{i}]", depth + 1) for i, v in enumerate(value)]
    if isinstance(value, dict):
        return {k: plain(v, f"{path}.{k}", depth + 1) for k, v in value.items()}
    raise ProtocolError(f"{path}: unsupported type {type(value).__name__}")


def clip(value: str, max_len: int = MAX_NAME_CHARS) -> str:
    """``value`` cut to ``max_len`` characters (the last one an ellipsis when cut): for names
    copied into outgoing messages, which must never fail their own validation."""
    return value if len(value) <= max_len else value[: max_len - 1] + "…"


RGB = array(integer(0, 255), min_len=3, max_len=3)
COMMAND = number(-100.0, 100.0)
STAMP = integer(0)
PUBLISHER_ID = integer(1, INT64_MAX)
MAX_WINNERS = 256

SCHEMAS: dict[str, Check] = {
    # --- sensors (ubf/<robot>/sensor/<kind>/<name>) ---
    "camera.seekcolor": record(
        {
            "bins": array(integer(0, 1 << 24), min_len=5, max_len=5),
            "total": integer(0, 1 << 24),
            "bearing_rad": number(-math.pi, math.pi, nullable=True),
            "latency_s": number(0.0, 60.0),
            "width": integer(1, 1 << 16),
            "height": integer(1, 1 << 16),
        },
        optional=("bearing_rad", "latency_s", "width", "height"),
    ),
    "range": record(
        {
            "range_mm": integer(0, 100_000, nullable=True),
            "status": text(choices=("ok", "too_close", "too_far")),
            "model": text(64),
            "min_mm": integer(0, 100_000),
            "max_mm": integer(0, 100_000),
        },
        optional=("model", "min_mm", "max_mm"),
    ),
    "encoders": record(
        {
            "left_edges": integer(),
            "right_edges": integer(),
            "left_counts": number(),
            "right_counts": number(),
            "errors": integer(0),
            "mode": text(16, choices=("commanded", "phase")),
        },
        optional=("left_counts", "right_counts", "errors", "mode"),
    ),
    "odometry": record(
        {"x_m": number(), "y_m": number(), "heading_rad": number(-math.pi - 1e-9, math.pi + 1e-9)}
    ),
    "motors.applied": record(
        {
            "speed": COMMAND,
            "turn": COMMAND,
            "left_ms": number(0.5, 2.5),
            "right_ms": number(0.5, 2.5),
            "left_dir": integer(-1, 1),
            "right_dir": integer(-1, 1),
            "reason": text(32),
        },
        optional=("reason",),
    ),
    "radio.message": record({"text": text(256)}),
    # --- commands (ubf/<robot>/cmd/<target>) ---
    "drive": record(
        {
            "speed": COMMAND,
            "turn": COMMAND,
            "based_on": record(
                {"source": text(MAX_NAME_CHARS), "seq": integer(0), "stamp_ns": STAMP},
                nullable=True,
            ),
            "tick": integer(0),
            "winners": array(text(MAX_NAME_CHARS), max_len=MAX_WINNERS),
            "hold": boolean,
        },
        optional=("based_on", "tick", "winners", "hold"),
    ),
    "seek_color": record({"lo": RGB, "hi": RGB}),
    "radio.send": record({"text": text(256)}),
    "leds": record({"mask": integer(0, 255)}),
    # --- infrastructure ---
    "heartbeat": record(
        {"component": text(128), "restarts": integer(0), "loop_lag_s": number(0.0),
         "running": text(8, choices=("yes", "no"))},
        optional=("restarts", "loop_lag_s", "running"),
    ),
    "clock": record({"real_time_factor": number(0.0, 1e6), "epoch": text(64)},
                    optional=("real_time_factor", "epoch")),
}
"""Known schemas and their data checks. Unknown schemas are accepted with :func:`plain`
checks only, so anyone can add a new kind of sensor without changing this module."""


def register_schema(name: str, check: Check) -> None:
    """Add a schema a component defines (e.g. a simulator's own messages). Registering the
    same name twice with a different check is a programming error."""
    existing = SCHEMAS.get(name)
    if existing is not None and existing is not check:
        raise ValueError(f"schema {name!r} is already registered")
    SCHEMAS[name] = check


@dataclass(frozen=True, slots=True)
class Message:
    """A decoded, validated payload."""

    schema: str
    stamp_ns: int
    seq: int
    data: dict[str, Any]
    period_s: float | None = None
    version: int = PROTOCOL_VERSION
    pub: int | None = None
    """The publisher's identity (random, new for every publisher instance) or ``None`` for a
    client that does not send one; see :mod:`ubf_async.ordering`."""


_ENVELOPE = record(
    {
        "schema": text(64),
        "v": integer(1, 1_000),
        "stamp_ns": STAMP,
        "seq": integer(0),
        "period_s": number(1e-6, 3600.0, nullable=True),
        "pub": PUBLISHER_ID,
        "data": lambda value, path: value,  # checked against the schema below
    },
    optional=("period_s", "pub"),
    extra=False,
)

_UNPACK_LIMITS = {
    "max_str_len": MAX_STR_LEN,
    "max_bin_len": MAX_PAYLOAD_BYTES,
    "max_array_len": MAX_CONTAINER_LEN,
    "max_map_len": MAX_CONTAINER_LEN,
    "max_ext_len": 0,
}


def check_data(schema: str, data: Any) -> dict[str, Any]:
    """Validate ``data`` against ``schema`` (generic checks for unknown schemas)."""
    checker = SCHEMAS.get(schema)
    if checker is None:
        if not isinstance(data, dict):
            raise ProtocolError(f"data: expected a map, got {type(data).__name__}")
        return plain(data, "data")
    return checker(data, "data")


def decode(payload: bytes | bytearray | memoryview, *, schema: str | None = None) -> Message:
    """Decode an untrusted payload. Raises :class:`ProtocolError` and nothing else.

    ``schema``, when given, is the schema the key requires (a drive key only accepts
    ``"drive"``).
    """
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise ProtocolError(f"payload of {len(payload)} bytes exceeds {MAX_PAYLOAD_BYTES}")
    try:
        raw = msgpack.unpackb(
            payload, raw=False, strict_map_key=True, use_list=True, **_UNPACK_LIMITS
        )
    except (ValueError, TypeError, RecursionError, msgpack.UnpackException) as exc:
        # ValueError covers ExtraData, FormatError, StackError and bad UTF-8.
        raise ProtocolError(f"not a valid msgpack payload: {exc}") from None
    try:
        envelope = _ENVELOPE(raw, "envelope")
        name = envelope["schema"]
        if envelope["v"] != PROTOCOL_VERSION:
            raise ProtocolError(f"envelope.v: version {envelope['v']} unsupported "
                                f"(this side speaks {PROTOCOL_VERSION})")
        if schema is not None and name != schema:
            raise ProtocolError(f"envelope.schema: expected {schema!r}, got {name!r}")
        data = check_data(name, envelope.get("data"))
    except RecursionError:
        raise ProtocolError("payload nested too deeply") from None
    return Message(
        schema=name,
        stamp_ns=envelope["stamp_ns"],
        seq=envelope["seq"],
        data=data,
        period_s=envelope.get("period_s"),
        pub=envelope.get("pub"),
    )


def encode(
    schema: str,
    data: Mapping[str, Any],
    *,
    stamp_ns: int,
    seq: int,
    period_s: float | None = None,
    pub: int | None = None,
) -> bytes:
    """Build a payload. The data is validated like incoming data, so this side never
    publishes what it would itself reject (raises :class:`ProtocolError`). ``pub`` is the
    publisher's identity (:class:`~ubf_async.bus.Publisher` sets it)."""
    checked = check_data(schema, dict(data))
    STAMP(stamp_ns, "stamp_ns")
    integer(0)(seq, "seq")
    envelope: dict[str, Any] = {
        "schema": schema, "v": PROTOCOL_VERSION, "stamp_ns": stamp_ns, "seq": seq,
        "data": checked,
    }
    if period_s is not None:
        envelope["period_s"] = float(period_s)
    if pub is not None:
        envelope["pub"] = PUBLISHER_ID(pub, "pub")
    return msgpack.packb(envelope, use_bin_type=True)
