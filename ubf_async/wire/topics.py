"""Every topic of a robot, declared once: its key, its schema name and its typed message.

This module is the wire contract in executable form (``docs/protocol.md`` is its prose). A
:class:`Topic` pairs a key pattern under ``ubf/<robot>/`` with the schema name carried in the
envelope and a :mod:`msgspec` ``Struct`` whose annotations are the message's constraints
(ranges, finiteness, string and list lengths, enumerations). Components, the aggregator, the
controller, remote behaviours and the inspector take their keys, schemas and types from here;
:mod:`ubf_async.wire.protocol` decodes and encodes through them (msgpack maps on the wire, so a
plain ``msgpack`` client keeps working).

Conventions of the message classes:

* every float is bounded (``Finite`` and narrower): msgspec accepts NaN and infinities in a
  plain ``float`` field, a bounded one refuses them;
* every string and array has a ``max_length``, and the payload as a whole is capped
  (:data:`~ubf_async.wire.protocol.MAX_PAYLOAD_BYTES`), so nothing grows without bound;
* optional fields default to ``None`` (or an empty tuple), and unknown fields are ignored, so
  a newer sender's extra field does not break an older receiver;
* messages are frozen: a sample handed to behaviours cannot be changed by one of them.

Sensors publish on ``sensor/<kind>/<name>``; their state source is ``"<kind>/<name>"`` and
:func:`sensor_topic` finds the topic of a kind (``"camera"`` → :data:`CAMERA`). Kinds not
declared here are welcome (anyone may add a sensor): their data is checked generically.
"""

from __future__ import annotations

import math
import string
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import Annotated, Any, Generic, Literal, TypeVar

import msgspec
from msgspec import Meta

from ubf_async.errors import ConfigurationError, ProtocolError
from ubf_async.wire.keys import (
    CLOCK_PATTERN,
    HEARTBEAT_PATTERN,
    STATUS_PATTERN,
    TREE_PATTERN,
    Keys,
    check_segment,
)

__all__ = ["BY_SCHEMA", "CAMERA", "CAMERA_VIEW", "CLOCK", "CONTROLLER_STATUS", "DRIVE", "ENCODERS",
           "HEARTBEAT", "INT64_MAX", "LARGEST_FLOAT", "LEDS", "LED_STATE", "LOCKSTEP_ACK",
           "MAX_ANNOUNCED", "MAX_ANNOUNCED_KEY_CHARS", "MAX_CONTAINER_LEN", "MAX_DEPTH",
           "MAX_IMAGE_BYTES", "MAX_NAME_CHARS", "MAX_REFUSAL_DETAIL", "MAX_STR_LEN",
           "MAX_TRACE_NODES", "MAX_TREE_DEPTH", "MAX_TTL_S", "MAX_WEIGHT", "MAX_WINNERS", "MOTORS",
           "ODOMETRY", "PRIORITY_LIMIT", "RADIO", "RADIO_SEND", "RANGE", "REFUSED",
           "REMOTES_STATUS", "RGB", "ROBOT_TIME", "SEEK_COLOR", "SENSORS", "SIM_PULSES",
           "SIM_TRUTH", "SIM_WORLD", "TOPICS", "TRACE", "TREE_OPS", "TREE_REPLY", "TREE_REQUEST",
           "VOTE", "BasedOn", "Byte", "CameraSeekcolor", "CameraView", "Command", "Count", "Data",
           "Drive", "Encoders", "Finite", "Heartbeat", "Int64", "LedState", "Leds", "LockstepAck",
           "Millimetres", "MotorsApplied", "Name", "NonNegative", "Odometry", "PlainData",
           "Priority", "Published", "PulseMs", "RadioMessage", "RadioSend", "Range",
           "RefusalNotice", "RobotTime", "SeekColor", "SimPulses", "SimTime", "SimTruth", "StampNs",
           "Text256", "TickTrace", "TickedBy", "Topic", "TraceNode", "TreeArbiter", "TreeNode",
           "TreeReply", "TreeRequest", "TreeSlot", "TruthBall", "TruthRobot", "Vote", "Weight",
           "matching", "plain", "require_field", "sensor_topic", "tree_depth"]

INT64_MAX = 2**63 - 1
MAX_NAME_CHARS = 128
"""Longest name a command or status carries back out: a state source (``"<kind>/<name>"``)
in ``based_on.source``, a behaviour in ``winners``."""
MAX_STR_LEN = 4096
MAX_CONTAINER_LEN = 4096
MAX_DEPTH = 8
"""Deepest nesting of generic data (:func:`plain`)."""
MAX_WINNERS = 256
MAX_TTL_S = 60.0
"""Largest ``ttl_s`` a vote may ask for (the robot clamps further)."""
PRIORITY_LIMIT = 1_000_000
MAX_WEIGHT = 1e6
LARGEST_FLOAT = 1.7e308

# ---------------------------------------------------------------------------------------------
# Constrained field types

Finite = Annotated[float, Meta(ge=-LARGEST_FLOAT, le=LARGEST_FLOAT)]
"""Any finite float (NaN and ±inf refused)."""
NonNegative = Annotated[float, Meta(ge=0.0, le=LARGEST_FLOAT)]
Int64 = Annotated[int, Meta(ge=-INT64_MAX, le=INT64_MAX)]
Count = Annotated[int, Meta(ge=0, le=INT64_MAX)]
StampNs = Annotated[int, Meta(ge=0, le=INT64_MAX)]
Command = Annotated[float, Meta(ge=-100.0, le=100.0)]
"""A drive command in percent of full speed or turn."""
Byte = Annotated[int, Meta(ge=0, le=255)]
RGB = tuple[Byte, Byte, Byte]
Millimetres = Annotated[int, Meta(ge=0, le=100_000)]
PulseMs = Annotated[float, Meta(ge=0.5, le=2.5)]
Name = Annotated[str, Meta(max_length=MAX_NAME_CHARS)]
Text256 = Annotated[str, Meta(max_length=256)]
Priority = Annotated[int, Meta(ge=-PRIORITY_LIMIT, le=PRIORITY_LIMIT)]
Weight = Annotated[float, Meta(ge=0.0, le=MAX_WEIGHT)]


class Data(msgspec.Struct, frozen=True, kw_only=True, omit_defaults=True):
    """Base of every typed message (the ``data`` of an envelope).

    Read fields as attributes (``drive.speed``). Reading by name also works, as from the map
    on the wire (``drive["speed"]``, ``drive.get("hold")``), but only for declared fields:
    a name the message does not have raises :class:`KeyError` naming the fields."""

    def __getitem__(self, name: str) -> Any:
        if name not in self.__struct_fields__:
            raise KeyError(f"{type(self).__name__} has no field {name!r} (fields: "
                           f"{', '.join(self.__struct_fields__)})")
        return getattr(self, name)

    def get(self, name: str, default: Any = None) -> Any:
        """The field ``name`` (``default`` when it is unset, ``None``); a name the message
        does not declare raises :class:`KeyError`."""
        value = self[name]
        return default if value is None else value


# ---------------------------------------------------------------------------------------------
# Sensors: ubf/<robot>/sensor/<kind>/<name>


class CameraSeekcolor(Data, frozen=True, kw_only=True):
    """The seekcolor algorithm's output for one frame (thesis §3.3.2)."""

    bins: Annotated[tuple[Annotated[int, Meta(ge=0, le=1 << 24)], ...],
                    Meta(min_length=5, max_length=5)]
    """Pink pixels per vertical fifth of the image, left to right."""
    total: Annotated[int, Meta(ge=0, le=1 << 24)]
    bearing_rad: Annotated[float, Meta(ge=-math.pi, le=math.pi)] | None = None
    latency_s: Annotated[float, Meta(ge=0.0, le=60.0)] | None = None
    """Capture to publication."""
    width: Annotated[int, Meta(ge=1, le=1 << 16)] | None = None
    height: Annotated[int, Meta(ge=1, le=1 << 16)] | None = None


class Range(Data, frozen=True, kw_only=True):
    """One IR range reading; ``range_mm`` is ``None`` unless ``status`` is ``"ok"``."""

    range_mm: Millimetres | None
    status: Literal["ok", "too_close", "too_far"]
    model: Annotated[str, Meta(max_length=64)] | None = None
    min_mm: Millimetres | None = None
    max_mm: Millimetres | None = None


class Encoders(Data, frozen=True, kw_only=True):
    """Quadrature edges (and counts) of both wheels since the encoders started."""

    left_edges: Int64
    right_edges: Int64
    left_counts: Finite | None = None
    right_counts: Finite | None = None
    errors: Count = 0
    mode: Literal["commanded", "phase"] | None = None
    left_rad_s: Finite | None = None
    """Wheel speed from the edges' time stamps, where the backend stamps them."""
    right_rad_s: Finite | None = None
    dropped: Count = 0
    """Edges lost because they came faster than they were read (the backend's buffer)."""


class Odometry(Data, frozen=True, kw_only=True):
    """Dead-reckoned pose from the encoders (start pose = origin)."""

    x_m: Finite
    y_m: Finite
    heading_rad: Annotated[float, Meta(ge=-math.pi - 1e-9, le=math.pi + 1e-9)]


class MotorsApplied(Data, frozen=True, kw_only=True):
    """What the motors really applied, and why (``reason``: command, timeout, init, ...)."""

    speed: Command
    turn: Command
    left_ms: PulseMs
    right_ms: PulseMs
    left_dir: Annotated[int, Meta(ge=-1, le=1)]
    right_dir: Annotated[int, Meta(ge=-1, le=1)]
    reason: Annotated[str, Meta(max_length=32)] | None = None


class LedState(Data, frozen=True, kw_only=True):
    """Which of a bank's LEDs are lit (bit ``i`` = LED ``i``)."""

    mask: Byte
    count: Annotated[int, Meta(ge=1, le=8)]

    def __post_init__(self) -> None:
        if self.mask >> self.count:
            raise ValueError(f"mask {self.mask:#04x} lights LEDs beyond the bank's {self.count}")


MAX_IMAGE_BYTES = 192 * 1024
"""An image on the bus is at most this big (the envelope's limit is 256 KiB)."""


class CameraView(Data, frozen=True, kw_only=True):
    """What a camera sees, for people and tools: the image seekcolor reads, compressed, with
    the matching pixels and the five bins marked. Published only while someone subscribes."""

    format: Literal["jpeg", "png"]
    data: Annotated[bytes, Meta(max_length=MAX_IMAGE_BYTES)]
    width: Annotated[int, Meta(ge=1, le=1 << 14)]
    height: Annotated[int, Meta(ge=1, le=1 << 14)]
    bins: Annotated[tuple[Annotated[int, Meta(ge=0, le=1 << 24)], ...],
                    Meta(min_length=5, max_length=5)]
    """The seekcolor bins of the same frame (as on ``sensor/camera/<name>``)."""


class RadioMessage(Data, frozen=True, kw_only=True):
    """A message the radio received."""

    text: Text256


# ---------------------------------------------------------------------------------------------
# Commands: ubf/<robot>/cmd/<target>


class BasedOn(Data, frozen=True, kw_only=True):
    """The sample a tick was based on (for end-to-end latency)."""

    source: Name
    seq: Count
    stamp_ns: StampNs


TickedBy = Literal["clock", "reflex", "sync", "event"]
"""What ran a controller's tick: its periodic clock, a reflex sample, the sync source's sample
(the thesis's loop) or the trigger's (``event``) — the labels of the status line's tick rates."""


class Drive(Data, frozen=True, kw_only=True, omit_defaults=False):
    """Speed and turn for the motors; ``hold`` repeats the last command between sync ticks;
    ``ticked_by`` says what ran the tick (``None`` on a hold, and from a sender that does not
    say). Every field goes on the wire, defaults included: simple clients read them by name."""

    speed: Command
    turn: Command
    based_on: BasedOn | None = None
    tick: Count | None = None
    winners: Annotated[tuple[Name, ...], Meta(max_length=MAX_WINNERS)] = ()
    hold: bool = False
    ticked_by: TickedBy | None = None


class SeekColor(Data, frozen=True, kw_only=True):
    """The colour range (RGB, inclusive) the camera's seekcolor counts."""

    lo: RGB
    hi: RGB

    def __post_init__(self) -> None:
        if any(a > b for a, b in zip(self.lo, self.hi, strict=True)):
            raise ValueError(f"lo {list(self.lo)} exceeds hi {list(self.hi)}")


class RadioSend(Data, frozen=True, kw_only=True):
    text: Text256


class Leds(Data, frozen=True, kw_only=True):
    """Which LEDs are lit, one bit each."""

    mask: Byte


# ---------------------------------------------------------------------------------------------
# Infrastructure


MAX_ANNOUNCED = 64
"""Publishers a heartbeat may announce."""
MAX_ANNOUNCED_KEY_CHARS = 256
"""The longest key a heartbeat announces (a publisher with a longer one is left out)."""


class Published(Data, frozen=True, kw_only=True):
    """One of a component's publishers, as its heartbeat announces it: the key and the
    ``pub`` identity its envelopes carry (``inspector info`` names a key's publishers by it)."""

    key: Annotated[str, Meta(max_length=MAX_ANNOUNCED_KEY_CHARS)]
    pub: Annotated[int, Meta(ge=1, le=INT64_MAX)]


class Heartbeat(Data, frozen=True, kw_only=True):
    component: Name
    restarts: Count = 0
    loop_lag_s: NonNegative = 0.0
    running: Literal["yes", "no"] = "yes"
    publishes: Annotated[tuple[Published, ...], Meta(max_length=MAX_ANNOUNCED)] = ()
    """Optional: what the component publishes now (absent: it does not say)."""
    pid: Annotated[int, Meta(ge=1, le=INT64_MAX)] | None = None
    """Optional: the component's process id on its host (with ``host``: which process to look
    at when the robot reports its samples)."""
    host: Annotated[str, Meta(max_length=253)] | None = None
    """Optional: the host the component runs on."""
    leaving: bool = False
    """Optional: true in the one heartbeat a component sends as it closes, before its token
    goes (a goodbye): the robot reports it left, not gone."""


class SimTime(Data, frozen=True, kw_only=True):
    """A simulator's time (the message on ``ubf/<robot>/clock``; the clock a process stamps
    with is :class:`ubf_async.clocks.clock.Clock`): the envelope's ``stamp_ns``; ``epoch``
    names the run, ``zid`` (optional) the zenoh session publishing it, so that a follower can
    tell the run of the robot it connected to from others that reach it."""

    real_time_factor: Annotated[float, Meta(ge=0.0, le=1e6)] | None = None
    epoch: Annotated[str, Meta(max_length=64)] | None = None
    zid: Annotated[str, Meta(max_length=64)] | None = None


class LockstepAck(Data, frozen=True, kw_only=True):
    """A lockstep participant has done everything it had to do at the simulated time in the
    envelope's ``stamp_ns`` (its samples or votes of that instant are already sent)."""


class RobotTime(Data, frozen=True, kw_only=True):
    """The robot host's clock (``CLOCK_MONOTONIC``) is the envelope's ``stamp_ns``; a process
    on another host learns its offset from it (:mod:`ubf_async.clocks.hostclock`)."""

    host: Annotated[str, Meta(max_length=253)] | None = None


MAX_REFUSAL_DETAIL = 512


class RefusalNotice(Data, frozen=True, kw_only=True):
    """The robot refused a sample or vote on the key this notice names
    (:mod:`ubf_async.runtime.refusals`): why, in a word and in the sentence it logged, and how many
    of that key's it has refused so far."""

    reason: Name
    """``future``, ``out_of_order``, ``malformed``, ``rejected`` …"""
    detail: Annotated[str, Meta(max_length=MAX_REFUSAL_DETAIL)]
    count: Annotated[int, Meta(ge=1, le=INT64_MAX)]


class Vote(Data, frozen=True, kw_only=True):
    """A remote behaviour's action and vote; unset action fields are ``None``."""

    vote: NonNegative
    speed: Command | None = None
    turn: Command | None = None
    seek_color: SeekColor | None = None
    message: Text256 | None = None
    leds: Byte | None = None
    ttl_s: Annotated[float, Meta(ge=1e-3, le=MAX_TTL_S)] | None = None
    priority: Priority | None = None
    weight: Weight | None = None


class SimPulses(Data, frozen=True, kw_only=True):
    """Motor pulses from a motors process to a simulator in another process."""

    left_ms: PulseMs
    right_ms: PulseMs


class TruthRobot(Data, frozen=True, kw_only=True):
    x_m: Finite
    y_m: Finite
    heading_rad: Finite
    speed_m_s: Finite | None = None
    yaw_rate_rad_s: Finite | None = None
    left_wheel_rad: Finite | None = None
    right_wheel_rad: Finite | None = None


class TruthBall(Data, frozen=True, kw_only=True):
    x_m: Finite
    y_m: Finite


class SimTruth(Data, frozen=True, kw_only=True):
    """Ground truth from the simulator (never seen by behaviours)."""

    time_s: Finite
    robot: TruthRobot
    ball: TruthBall | None = None


class TreeArbiter(Data, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """An arbiter with parameters in a :class:`TreeRequest` (``set_arbiter``); a robot file's
    is :class:`ubf_async.assembly.robotfile.ArbiterSpec`."""

    type: Annotated[str, Meta(max_length=200)]
    params: dict[Annotated[str, Meta(max_length=MAX_NAME_CHARS)], Any] = {}
    """Plain values (checked by :func:`plain`); the arbiter's factory types them."""

    def __post_init__(self) -> None:
        plain(self.params, "params")


TREE_OPS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    # op: (required fields, optional fields)
    "show": ((), ()),
    "set_arbiter": (("composite", "arbiter"), ()),
    "set_child": (("composite", "child"), ("priority", "weight")),
    "load": (("tree",), ()),
}


class TreeRequest(Data, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """A change (or a look) asked of the live tree; which fields each ``op`` takes is
    :data:`TREE_OPS`. ``tree`` is a robot-file fragment, text or UTF-8 bytes (for
    fragments longer than :data:`MAX_STR_LEN` characters)."""

    op: Literal["show", "set_arbiter", "set_child", "load"]
    composite: Name | None = None
    child: Name | None = None
    arbiter: Annotated[str, Meta(max_length=200)] | TreeArbiter | None = None
    priority: Priority | None = None
    weight: Weight | None = None
    tree: Any = None
    """A str of at most :data:`MAX_STR_LEN` characters, or UTF-8 bytes (msgspec cannot type
    a union of both: checked below)."""

    def __post_init__(self) -> None:
        required, optional = TREE_OPS[self.op]
        given = [name for name in ("composite", "child", "arbiter", "priority", "weight",
                                   "tree") if getattr(self, name) is not None]
        missing = [name for name in required if name not in given]
        if missing:
            raise ValueError(f"op {self.op!r} needs " + ", ".join(map(repr, missing)))
        stray = [name for name in given if name not in (*required, *optional)]
        if stray:
            raise ValueError(f"op {self.op!r} takes no " + ", ".join(map(repr, stray)))
        if self.op == "set_child" and self.priority is None and self.weight is None:
            raise ValueError("op 'set_child' needs 'priority' and/or 'weight'")
        if isinstance(self.tree, bytes):
            self.tree.decode("utf-8")  # UnicodeDecodeError is a ValueError
        elif isinstance(self.tree, str):
            if len(self.tree) > MAX_STR_LEN:
                raise ValueError(f"tree: a fragment of over {MAX_STR_LEN} characters goes as "
                                 f"UTF-8 bytes")
        elif self.tree is not None:
            raise ValueError(f"tree: expected text or UTF-8 bytes, got {type(self.tree).__name__}")


MAX_TREE_DEPTH = 64
"""Deepest tree a reply carries (robot files allow 32 levels)."""


class TreeNode(Data, frozen=True, kw_only=True):
    name: Name
    kind: Literal["composite", "behavior", "remote"]
    type: Annotated[str, Meta(max_length=200)] | None = None
    arbiter: Annotated[str, Meta(max_length=MAX_STR_LEN)] | None = None
    priority: Priority | None = None
    weight: Weight | None = None
    children: Annotated[tuple[TreeNode, ...], Meta(max_length=4096)] | None = None


class TreeSlot(Data, frozen=True, kw_only=True):
    composite: Name
    name: Name
    priority: Priority
    weight: Weight


class TreeReply(Data, frozen=True, kw_only=True):
    """``ok`` with the ``tree`` (and remote ``slots``), or not ``ok`` with the ``error``."""

    ok: bool
    op: Annotated[str, Meta(max_length=32)] | None = None
    version: Count | None = None
    error: Annotated[str, Meta(max_length=MAX_STR_LEN)] | None = None
    tree: TreeNode | None = None
    slots: Annotated[tuple[TreeSlot, ...], Meta(max_length=4096)] = ()

    def __post_init__(self) -> None:
        if self.ok and self.tree is None:
            raise ValueError("an ok reply carries the tree")
        if not self.ok and self.error is None:
            raise ValueError("a refusal carries an error")
        if self.tree is not None and tree_depth(self.tree) > MAX_TREE_DEPTH:
            raise ValueError(f"tree deeper than {MAX_TREE_DEPTH}")


def tree_depth(node: TreeNode) -> int:
    """Levels below and including ``node`` (iterative: any depth that decoded is fine)."""
    deepest, stack = 0, [(node, 1)]
    while stack:
        current, depth = stack.pop()
        deepest = max(deepest, depth)
        stack.extend((child, depth + 1) for child in current.children or ())
    return deepest


# ---------------------------------------------------------------------------------------------
# Generic data


def plain(value: Any, path: str = "data", depth: int = 0) -> Any:
    """Generic check for data of undeclared schemas: nil, bool, int64, finite float, str
    (at most :data:`MAX_STR_LEN` characters), bytes, arrays (at most
    :data:`MAX_CONTAINER_LEN` items) and maps keyed by strings of at most
    :data:`MAX_NAME_CHARS` characters, nested at most :data:`MAX_DEPTH`
    deep. Returns the value with tuples as lists; raises
    :class:`~ubf_async.errors.ProtocolError`."""
    if depth > MAX_DEPTH:
        raise ProtocolError(f"{path}: nested deeper than {MAX_DEPTH}")
    if value is None or isinstance(value, bool | bytes):
        return value
    if isinstance(value, str):
        if len(value) > MAX_STR_LEN:
            raise ProtocolError(f"{path}: string longer than {MAX_STR_LEN}")
        return value
    if isinstance(value, int):
        if not -INT64_MAX <= value <= INT64_MAX:
            raise ProtocolError(f"{path}: {value} outside the 64-bit integer range")
        return value
    if isinstance(value, float):
        if value != value or value in (float("inf"), float("-inf")):
            raise ProtocolError(f"{path}: {value} is not finite")
        return value
    if isinstance(value, list | tuple):
        if len(value) > MAX_CONTAINER_LEN:
            raise ProtocolError(f"{path}: array longer than {MAX_CONTAINER_LEN}")
        return [plain(v, f"{path}[{i}]", depth + 1) for i, v in enumerate(value)]
    if isinstance(value, dict):
        if len(value) > MAX_CONTAINER_LEN:
            raise ProtocolError(f"{path}: map larger than {MAX_CONTAINER_LEN}")
        out = {}
        for k, v in value.items():
            if not isinstance(k, str):
                raise ProtocolError(f"{path}: map key {k!r} is not a string")
            if len(k) > MAX_NAME_CHARS:
                raise ProtocolError(f"{path}: map key {k[:40]!r}… longer than {MAX_NAME_CHARS}")
            out[k] = plain(v, f"{path}.{k}", depth + 1)
        return out
    raise ProtocolError(f"{path}: unsupported type {type(value).__name__}")




MAX_TRACE_NODES = 512
"""Most behaviours one tick's trace lists."""


class TraceNode(Data, frozen=True, kw_only=True):
    """One behaviour's part in a tick; a trace lists them depth first (the root at depth 0)."""

    name: Name
    depth: Annotated[int, Meta(ge=0, le=MAX_TREE_DEPTH)]
    won: bool = False
    """This behaviour's action contributed to its parent's result."""
    arbiter: Name | None = None
    """For a composite, its arbiter's name."""
    speed: Command | None = None
    turn: Command | None = None
    vote: NonNegative | None = None
    """The action's vote; all three unset when the behaviour had no opinion."""
    fault: Text256 | None = None
    """Why the behaviour did not run properly (it raised, or is quarantined)."""


class TickTrace(Data, frozen=True, kw_only=True):
    """The behaviour tree's trace of one controller tick (why the robot did what it did)."""

    tick: Count
    nodes: Annotated[tuple[TraceNode, ...], Meta(max_length=MAX_TRACE_NODES)]


# ---------------------------------------------------------------------------------------------
# Topics

T = TypeVar("T")

PlainData = dict[Annotated[str, Meta(max_length=MAX_NAME_CHARS)], Any]
"""The data of a schema not declared here: a map of plain values, checked generically
(:func:`ubf_async.wire.protocol.plain`)."""


@dataclass(frozen=True)
class Topic(Generic[T]):
    """One topic: ``pattern`` (under ``ubf/<robot>/``, with ``{placeholders}``), the
    ``schema`` name in its envelopes and the ``type`` of its data."""

    name: str
    pattern: str
    schema: str
    type: type[T]
    doc: str = ""
    placeholders: tuple[str, ...] = field(init=False)

    def __post_init__(self) -> None:
        names = tuple(f for _, f, _, _ in string.Formatter().parse(self.pattern) if f)
        object.__setattr__(self, "placeholders", names)

    def key(self, keys: Keys, *args: str, **parts: str) -> str:
        """The concrete key of this topic for a robot: ``CAMERA.key(keys, "front")``."""
        values = dict(zip(self.placeholders, args, strict=False)) | parts
        missing = [p for p in self.placeholders if p not in values]
        if missing or len(values) != len(self.placeholders):
            raise TypeError(f"topic {self.name!r} ({self.pattern}) needs "
                            f"{', '.join(self.placeholders) or 'no parts'}, got {values}")
        return f"{keys.prefix}/" + self.pattern.format(
            **{k: check_segment(k, v) for k, v in values.items()})

    def key_expr(self, keys: Keys) -> str:
        """Every key of this topic (placeholders as ``*``)."""
        return f"{keys.prefix}/" + self.pattern.format(**dict.fromkeys(self.placeholders, "*"))

    @property
    def kind(self) -> str | None:
        """For a sensor topic, its kind (``sensor/<kind>/{name}``)."""
        parts = self.pattern.split("/")
        return parts[1] if len(parts) == 3 and parts[0] == "sensor" else None

    @property
    def fields(self) -> tuple[str, ...]:
        """Field names of the data (empty for generic data)."""
        return tuple(getattr(self.type, "__struct_fields__", ()))


CAMERA = Topic("camera", "sensor/camera/{name}", "camera.seekcolor", CameraSeekcolor,
               "seekcolor bins of one camera frame")
RANGE = Topic("range", "sensor/range/{name}", "range", Range, "one IR range reading")
ENCODERS = Topic("encoders", "sensor/encoders/{name}", "encoders", Encoders,
                 "quadrature edges and counts")
ODOMETRY = Topic("odometry", "sensor/odometry/{name}", "odometry", Odometry,
                 "dead-reckoned pose")
MOTORS = Topic("motors", "sensor/motors/{name}", "motors.applied", MotorsApplied,
               "what the motors applied")
LED_STATE = Topic("led_state", "sensor/leds/{name}", "leds.state", LedState,
                  "which LEDs are lit")
RADIO = Topic("radio", "sensor/radio/{name}", "radio.message", RadioMessage,
              "a message the radio received")

DRIVE = Topic("drive", "cmd/drive", "drive", Drive, "speed and turn for the motors")
SEEK_COLOR = Topic("seek_color", "cmd/seek_color", "seek_color", SeekColor,
                   "the colour the camera counts")
RADIO_SEND = Topic("radio_send", "cmd/radio", "radio.send", RadioSend, "a message to send")
LEDS = Topic("leds", "cmd/leds", "leds", Leds, "which LEDs are lit")

HEARTBEAT = Topic("heartbeat", HEARTBEAT_PATTERN, "heartbeat", Heartbeat,
                  "a component's heartbeat")
CLOCK = Topic("clock", CLOCK_PATTERN, "clock", SimTime,
              "simulated time (absent on wall-clock robots)")
LOCKSTEP_ACK = Topic("lockstep_ack", "lockstep/{participant}", "lockstep.ack", LockstepAck,
                     "a lockstep participant's acknowledgement of a simulated instant "
                     "(its liveliness token, on the same key, says it takes part)")
ROBOT_TIME = Topic("robot_time", "time", "robot.time", RobotTime,
                   "the robot host's clock, for processes on other hosts (absent when "
                   "simulating)")
VOTE = Topic("vote", "vote/{composite}/{behavior}", "vote", Vote,
             "a remote behaviour's vote in a composite")
REFUSED = Topic("refused", "refused/{topic}/{group}/{name}", "refusal", RefusalNotice,
                "the robot refused a sample or vote on ubf/<robot>/<topic>/<group>/<name> "
                "(sensor/<kind>/<name>, vote/<composite>/<behaviour>)")
CONTROLLER_STATUS = Topic("controller_status", STATUS_PATTERN, "controller.status",
                          PlainData, "the controller's status")
REMOTES_STATUS = Topic("remotes_status", STATUS_PATTERN, "remotes.status", PlainData,
                       "the remote behaviours' status")
TREE_REQUEST = Topic("tree_request", TREE_PATTERN, "tree.request", TreeRequest,
                     "a query to the live tree")
TREE_REPLY = Topic("tree_reply", TREE_PATTERN, "tree.reply", TreeReply,
                   "the live tree's answer")
SIM_TRUTH = Topic("sim_truth", "sim/truth", "sim.truth", SimTruth,
                  "the simulator's ground truth")
SIM_WORLD = Topic("sim_world", "sim/world", "sim.world", PlainData,
                  "the simulator's full snapshot, for sim-backed devices in other processes")
SIM_PULSES = Topic("sim_pulses", "sim/pulses", "sim.pulses", SimPulses,
                   "motor pulses from a motors process to the simulator")
CAMERA_VIEW = Topic("camera_view", "view/camera/{name}", "camera.view", CameraView,
                    "the camera's image with the pink pixels and the bins marked, while "
                    "anyone subscribes")
TRACE = Topic("trace", "trace", "controller.trace", TickTrace,
              "the behaviour tree's trace of each tick, published after its command")

TOPICS: tuple[Topic[Any], ...] = (
    CAMERA, RANGE, ENCODERS, ODOMETRY, MOTORS, LED_STATE, RADIO,
    DRIVE, SEEK_COLOR, RADIO_SEND, LEDS,
    HEARTBEAT, CLOCK, LOCKSTEP_ACK, ROBOT_TIME, VOTE, REFUSED, CONTROLLER_STATUS,
    REMOTES_STATUS, TREE_REQUEST, TREE_REPLY, SIM_TRUTH, SIM_WORLD, SIM_PULSES, TRACE,
    CAMERA_VIEW,
)
"""Every declared topic."""

BY_SCHEMA: Mapping[str, Topic[Any]] = {t.schema: t for t in TOPICS}
SENSORS: Mapping[str, Topic[Any]] = {t.kind: t for t in TOPICS if t.kind is not None}
"""Sensor topics by kind."""

assert len(BY_SCHEMA) == len(TOPICS), "a schema is declared twice"


def sensor_topic(source: str) -> Topic[Any] | None:
    """The topic of a state source (``"camera/front"`` → :data:`CAMERA`), ``None`` for a
    kind not declared here."""
    return SENSORS.get(source.partition("/")[0])


def require_field(source: str, field_name: str, *, who: str = "") -> None:
    """Raise :class:`~ubf_async.errors.ConfigurationError` if ``source``'s kind is declared
    and has no field ``field_name`` — for behaviours and predicates to call when they are
    built, so a typo fails when a robot file loads, not silently every tick."""
    topic = sensor_topic(source)
    if topic is None or field_name in topic.fields:
        return
    raise ConfigurationError(
        f"{who + ': ' if who else ''}{source!r} is a {topic.kind} source; its samples have no "
        f"field {field_name!r} (fields: {', '.join(topic.fields)})")


def matching(keys: Keys, key: str) -> Iterator[Topic[Any]]:
    """The topics whose pattern matches the concrete ``key`` of ``keys``' robot."""
    head = f"{keys.prefix}/"
    if not key.startswith(head):
        return
    parts = key[len(head):].split("/")
    for topic in TOPICS:
        pattern = topic.pattern.split("/")
        if len(pattern) == len(parts) and all(
                p.startswith("{") or p == k for p, k in zip(pattern, parts, strict=True)):
            yield topic
