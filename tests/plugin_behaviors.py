"""A user's own behaviours, referenced from robot files as ``tests.plugin_behaviors:NAME``."""

from __future__ import annotations

from typing import Annotated

import msgspec

from ubf_async.core.action import Action
from ubf_async.core.behavior import Behavior
from ubf_async.core.state import State


class Spin(Behavior):
    """Turn on the spot at ``turn`` whatever the sensors say."""

    def __init__(self, *, turn: Annotated[float, msgspec.Meta(ge=-100, le=100)] = 60.0,
                 vote: float = 1.0) -> None:
        super().__init__()
        self.turn = turn
        self.vote = vote

    def act(self, state: State) -> Action | None:
        return Action(speed=0.0, turn=self.turn, vote=self.vote)


def not_a_behavior() -> str:
    """A factory that returns the wrong thing (robot files must refuse it)."""
    return "surprise"


class SpinWhenClose(Behavior):
    """A behaviour whose factory names it (``spin_when_close``, not its class name)."""

    def __init__(self, *, name: str = "spin_when_close", turn: float = 60.0) -> None:
        super().__init__(name=name)
        self.turn = turn

    def act(self, state: State) -> Action | None:
        return Action(speed=0.0, turn=self.turn)


def needs_a_name(*, name: str) -> Behavior:
    """A factory that requires a name: the loader gives it the one it is referenced by."""
    return SpinWhenClose(name=name)


class Raising(Behavior):
    """A behaviour whose every tick fails: its composite quarantines it."""

    def act(self, state: State) -> Action | None:
        raise RuntimeError("this behaviour always fails")
