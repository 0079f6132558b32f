"""What the robot knows now: the UBF *state*, a read-only snapshot of the latest samples."""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from ubf_async.action import Action


@dataclass(frozen=True, slots=True, kw_only=True)
class Reading:
    """The latest sample of one source.

    ``value`` holds the sample's fields (e.g. ``{"bins": [0, 3, 120, 5, 0], ...}`` for a
    camera). ``stamp_ns`` is when the sample was taken (robot clock), ``age_s`` how old it was
    when the snapshot was made, and ``stale`` whether that age exceeds the source's limit.
    """

    value: Mapping[str, Any]
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

    def value(self, source: str, field: str, default: Any = None) -> Any:
        """A field of a fresh reading, or ``default`` when missing or stale."""
        reading = self.fresh(source)
        if reading is None:
            return default
        return reading.value.get(field, default)

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

        Keyword names use ``__`` for ``/``: ``State.of(camera__front={"bins": [...]})``.
        """
        readings = {
            name.replace("__", "/"): Reading(value=value, stamp_ns=now_ns)
            for name, value in values.items()
        }
        return cls(readings, now_ns=now_ns, previous_action=previous_action)
