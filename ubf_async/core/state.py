"""What the robot knows now: the UBF *state*, a read-only snapshot of the latest samples."""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, TypeVar

import msgspec

from ubf_async.errors import ProtocolError, UnknownFieldError
from ubf_async.wire import topics

if TYPE_CHECKING:
    from ubf_async.core.action import Action

__all__ = ["Reading", "State", "typed"]

T = TypeVar("T")


@dataclass(frozen=True, slots=True, kw_only=True)
class Reading:
    """The latest sample of one source.

    ``value`` is the sample's typed message (:mod:`ubf_async.wire.topics`, e.g. a
    :class:`~ubf_async.wire.topics.CameraSeekcolor` with ``bins == (0, 3, 120, 5, 0)``), or a map
    of plain values for a kind of sensor not declared there. ``stamp_ns`` is when the sample
    was taken (robot clock), ``age_s`` how old it was when the snapshot was made, and
    ``stale`` whether that age exceeds the source's limit.
    """

    value: Any
    stamp_ns: int
    seq: int = 0
    age_s: float = 0.0
    stale: bool = False


class State(Mapping[str, Reading]):
    """Read-only snapshot handed to every behaviour on a tick.

    Sources are named ``"<kind>/<name>"`` after their key (``ubf/<robot>/sensor/camera/front``
    → ``"camera/front"``). ``now_ns`` is the robot clock at the snapshot, ``previous_action``
    the action the controller published on the previous tick (``None`` before the first).
    """

    __slots__ = ("_readings", "now_ns", "previous_action")

    def __init__(
        self,
        readings: Mapping[str, Reading] | None = None,
        *,
        now_ns: int = 0,
        previous_action: Action | None = None,
    ) -> None:
        self._readings: dict[str, Reading] = dict(readings or {})
        self.now_ns = now_ns
        self.previous_action = previous_action

    def __getitem__(self, source: str) -> Reading:
        return self._readings[source]

    def __iter__(self) -> Iterator[str]:
        return iter(self._readings)

    def __len__(self) -> int:
        return len(self._readings)

    def fresh(self, source: str) -> Reading | None:
        """The reading of ``source`` if present and not stale, else ``None``."""
        reading = self._readings.get(source)
        if reading is None or reading.stale:
            return None
        return reading

    def sample(self, topic: topics.Topic[T], name: str) -> T | None:
        """The typed message of the fresh reading of ``topic``'s source ``name``
        (``state.sample(topics.CAMERA, "front")``), ``None`` when missing or stale."""
        reading = self.fresh(f"{topic.kind}/{name}")
        if reading is None or not isinstance(reading.value, topic.type):
            return None
        return reading.value

    def camera(self, name: str = "front") -> topics.CameraSeekcolor | None:
        """The fresh seekcolor sample of camera ``name``: ``state.camera().bins``."""
        return self.sample(topics.CAMERA, name)

    def range(self, name: str = "front") -> topics.Range | None:
        """The fresh reading of range finder ``name``: ``state.range("front").range_mm``."""
        return self.sample(topics.RANGE, name)

    def encoders(self, name: str) -> topics.Encoders | None:
        return self.sample(topics.ENCODERS, name)

    def odometry(self, name: str) -> topics.Odometry | None:
        return self.sample(topics.ODOMETRY, name)

    def motors(self, name: str) -> topics.MotorsApplied | None:
        return self.sample(topics.MOTORS, name)

    def radio(self, name: str) -> topics.RadioMessage | None:
        return self.sample(topics.RADIO, name)

    def value(self, source: str, field: str, default: Any = None) -> Any:
        """A field of a fresh reading, or ``default`` when missing, stale or unset (``None``).

        Raises :class:`UnknownFieldError` when ``source``'s kind is declared in
        :mod:`ubf_async.wire.topics` without that field: a typo is an error, not an abstention
        forever. (Typed access — ``state.camera("front")`` — catches it before running.)"""
        topic = topics.sensor_topic(source)
        if topic is not None and field not in topic.fields:
            raise UnknownFieldError(
                f"{source!r} is a {topic.kind} source; its samples have no field {field!r} "
                f"(fields: {', '.join(topic.fields)})")
        reading = self.fresh(source)
        if reading is None:
            return default
        value = reading.value
        if isinstance(value, Mapping):
            return value.get(field, default)
        result = getattr(value, field, default)
        return default if result is None else result

    def __repr__(self) -> str:
        inner = ", ".join(
            f"{name}: age={r.age_s:.3f}s{' STALE' if r.stale else ''}"
            for name, r in sorted(self._readings.items())
        )
        return f"State(now_ns={self.now_ns}, {{{inner}}})"

    @classmethod
    def of(cls, *, now_ns: int = 0, previous_action: Action | None = None,
           **values: Mapping[str, Any]) -> State:
        """Build a snapshot from plain values, all fresh and stamped ``now_ns`` — handy in tests.

        Keyword names use ``__`` for ``/``: ``State.of(camera__front={"bins": [...],
        "total": 5})``. Values of declared kinds are checked and typed as the wire would
        (raises :class:`~ubf_async.errors.ProtocolError`).
        """
        readings = {
            name.replace("__", "/"): Reading(value=typed(name.replace("__", "/"), value),
                                             stamp_ns=now_ns)
            for name, value in values.items()
        }
        return cls(readings, now_ns=now_ns, previous_action=previous_action)


def typed(source: str, value: Any) -> Any:
    """``value`` as the typed message of ``source``'s kind (a map converted and checked;
    a message of the right type kept), unchanged for an undeclared kind."""
    topic = topics.sensor_topic(source)
    if topic is None or isinstance(value, topic.type):
        return value
    try:
        return msgspec.convert(value, topic.type)
    except (msgspec.MsgspecError, ValueError, TypeError) as exc:
        raise ProtocolError(f"{source}: not a {topic.schema} sample: {exc}") from None
