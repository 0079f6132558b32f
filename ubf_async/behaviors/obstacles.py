"""Obstacle avoidance from the IR range finders: the ``avoid`` behaviour.

Range sources are named ``range/<name>`` and carry ``status`` (``"ok"``, ``"too_close"``,
``"too_far"``) and ``range_mm`` (see docs/protocol.md). A reading counts as an obstacle when
it is fresh and either ``status == "ok"`` with ``range_mm ≤ near_mm``, or ``status ==
"too_close"`` (nearer than the sensor can measure: 0 mm). ``too_far`` and stale readings
never count.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Annotated

import msgspec

from ubf_async.behaviors.params import Command, Millimetres, check
from ubf_async.core.action import Action
from ubf_async.core.behavior import Behavior
from ubf_async.core.state import State
from ubf_async.wire.topics import require_field

__all__ = ["DEFAULT_HOLD_S", "DEFAULT_NEAR_MM", "RANGE_PREFIX", "Avoid", "nearest_obstacle"]

RANGE_PREFIX = "range/"
DEFAULT_NEAR_MM = 250
DEFAULT_HOLD_S = 1.5


def nearest_obstacle(
    state: State, near_mm: int, sources: Sequence[str] = ()
) -> tuple[str, int] | None:
    """``(source, mm)`` of the nearest obstacle within ``near_mm`` among ``sources`` (every
    ``range/*`` source of the state when empty), or ``None``."""
    best: tuple[str, int] | None = None
    for source in sources or [s for s in state if s.startswith(RANGE_PREFIX)]:
        status = state.value(source, "status")
        mm = state.value(source, "range_mm")
        if status == "too_close":
            mm = 0
        elif status != "ok" or mm is None:
            continue
        if mm <= near_mm and (best is None or mm < best[1]):
            best = (source, mm)
    return best


class Avoid(Behavior):
    """Back away from the nearest obstacle closer than ``near_mm``, and keep backing away for
    ``hold_s`` after it was last that near; abstain otherwise.

    It backs at ``speed`` and turns by ``turn`` — away from the side of the sensor when its
    name says ``left`` or ``right`` (an obstacle on the left: turn right), else to the left —
    with a vote of ``1 + closeness`` (1 at ``near_mm``, 2 when touching), so it grows as the
    obstacle gets nearer. ``sources`` are the range sources to watch (default: every
    ``range/*`` source of the state).

    Why the hold: a range finder's beam is a thin line from the robot's nose, and the robot is
    7 cm wide. Without it, avoid lets go the moment its turn swings the beam off the edge of an
    obstacle, whatever (chase) pulls the robot back toward it swings the beam onto it again,
    and the two dither along the obstacle's face, creeping forward, until the nose is against
    it with the beam just clear of the corner and half the body pressed on the obstacle
    (the built-in ``obstacle-course``). Holding the turn for ``hold_s`` turns the body, not
    just the beam, clear of the edge before anything else may steer it back; ``0`` lets go
    at once.
    """

    def __init__(
        self,
        *,
        name: str = "avoid",
        sources: Sequence[str] = (),
        near_mm: Millimetres = DEFAULT_NEAR_MM,
        speed: Command = -30.0,
        turn: Command = 60.0,
        hold_s: Annotated[float, msgspec.Meta(ge=0, le=60)] = DEFAULT_HOLD_S,
    ) -> None:
        super().__init__(name=name)
        check("Avoid", "near_mm", near_mm, gt=0, integer=True)
        check("Avoid", "speed", speed, ge=-100, le=100)
        check("Avoid", "turn", turn, ge=-100, le=100)
        check("Avoid", "hold_s", hold_s, ge=0, le=60)
        for source in sources:
            require_field(source, "range_mm", who=f"Avoid {name!r}")
        self.sources = list(sources)
        self.near_mm = near_mm
        self.speed = speed
        self.turn = turn
        self.hold_ns = round(hold_s * 1e9)
        self._held: tuple[int, Action] | None = None
        """Until when (robot clock) the last avoiding action holds, and that action."""

    def reset(self) -> None:
        self._held = None

    def nearest(self, state: State) -> tuple[str, int] | None:
        """``(source, mm)`` of the nearest obstacle within ``near_mm``, if any."""
        return nearest_obstacle(state, self.near_mm, self.sources)

    def act(self, state: State) -> Action | None:
        found = self.nearest(state)
        if found is None:
            if self._held is not None and state.now_ns < self._held[0]:
                return self._held[1]
            self._held = None
            return None
        source, mm = found
        side = source.partition("/")[2]
        turn = -self.turn if "left" in side else self.turn  # obstacle on the left: go right
        closeness = 1.0 - mm / self.near_mm
        action = Action(speed=self.speed, turn=turn, vote=1.0 + closeness)
        if self.hold_ns > 0:
            # Held at the lowest vote: the obstacle is no longer seen within near_mm.
            self._held = (state.now_ns + self.hold_ns, Action(speed=self.speed, turn=turn,
                                                              vote=1.0))
        return action
