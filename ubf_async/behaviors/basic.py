"""Two trivial behaviours a robot file often needs: ``stop`` and ``drive``.

* :class:`Stop` always asks for speed 0, turn 0 — a fallback at the lowest priority, or the
  "else" branch of a :class:`~ubf_async.core.arbiters.Conditional`.
* :class:`ConstantDrive` always asks for a constant speed and turn (cruise, spin in place, …).
"""

from __future__ import annotations

from ubf_async.behaviors.params import Command, VoteWeight, check
from ubf_async.core.action import Action
from ubf_async.core.behavior import Behavior
from ubf_async.core.state import State

__all__ = ["ConstantDrive", "Stop"]


class Stop(Behavior):
    """Always ``Action(speed=0, turn=0)`` with vote ``vote``."""

    def __init__(self, *, name: str = "stop", vote: VoteWeight = 1.0) -> None:
        super().__init__(name=name)
        check("Stop", "vote", vote, ge=0)
        self.action = Action(speed=0.0, turn=0.0, vote=vote)

    def act(self, state: State) -> Action | None:
        return self.action


class ConstantDrive(Behavior):
    """Always ``Action(speed=speed, turn=turn)`` with vote ``vote``."""

    def __init__(
        self,
        *,
        name: str = "drive",
        speed: Command = 0.0,
        turn: Command = 0.0,
        vote: VoteWeight = 1.0,
    ) -> None:
        super().__init__(name=name)
        check("ConstantDrive", "speed", speed, ge=-100, le=100)
        check("ConstantDrive", "turn", turn, ge=-100, le=100)
        check("ConstantDrive", "vote", vote, ge=0)
        self.action = Action(speed=speed, turn=turn, vote=vote)

    def act(self, state: State) -> Action | None:
        return self.action
