"""The thesis's demonstration, "seek the big pink ball" (§3.4.2): search, chase and flee.

All three read the camera's seekcolor result from the state, by default the source
``"camera/front"`` (key ``ubf/<robot>/sensor/camera/front``), fields:

* ``bins`` — five pink-pixel counts in image order, left to right (bin centres at +14°, +7°,
  0°, −7°, −14°; positive = to the robot's left);
* ``total`` — their sum.

When the camera reading is missing or stale all three abstain: a robot that cannot see must
not search, chase or flee on old news (the controller then commands a stop).

*chase* steers by the most populated bin. *flee* reads the distance from the total count
(the ball has a fixed size, so its pixel count gives the distance — §3.4.2): with the ball
centred that is the centre bin's count, the thesis's "140 pink pixels" at the comfortable
distance, and unlike a single bin's count it does not drop when the ball straddles two bins,
which would let the robot creep closer than comfortable.

The three are registered as the behaviours ``search``, ``chase`` and ``flee`` (entry-point
group ``ubf_async.behaviors``); their keyword parameters, with the thesis's numbers as
defaults, are what a robot file may set. ``name`` and ``rng`` are injected by the loader.
"""

from __future__ import annotations

import random
from collections.abc import Sequence
from typing import Annotated

import msgspec

from ubf_async.behaviors.params import Command, LedMask, Pixels, check
from ubf_async.core.action import Action
from ubf_async.core.arbiters import PriorityMerge
from ubf_async.core.behavior import Behavior, Child, Composite
from ubf_async.core.state import State
from ubf_async.wire.topics import require_field

__all__ = ["BIN_TURNS", "CAMERA_SOURCE", "Chase", "Flee", "Search", "pink_bins", "seek_pink_ball"]

CAMERA_SOURCE = "camera/front"
BIN_TURNS: tuple[float, ...] = (60.0, 30.0, 0.0, -30.0, -60.0)
"""chase's turn for pink concentrated in each bin (image order: outer left … outer right)."""


def pink_bins(state: State, source: str = CAMERA_SOURCE) -> Sequence[int] | None:
    """The five bin counts of a fresh camera reading, or ``None`` if there is none."""
    bins = state.value(source, "bins")
    if bins is None or len(bins) != len(BIN_TURNS):
        return None
    return bins


class Chase(Behavior):
    """Drive at the pink: speed +40, turn 0 / ±30 / ±60 toward the most populated bin.

    Acts only when at least ``min_pixels`` pink pixels are seen. On equal counts the bin
    nearer the centre wins (turn less when unsure). ``leds``, when given, is lit while it
    chases (the LEDs show that the robot sees pink).
    """

    def __init__(
        self,
        *,
        name: str = "chase",
        source: str = CAMERA_SOURCE,
        speed: Command = 40.0,
        min_pixels: Pixels = 1,
        leds: LedMask | None = None,
    ) -> None:
        super().__init__(name=name)
        check("Chase", "speed", speed, ge=-100, le=100)
        check("Chase", "min_pixels", min_pixels, ge=0, integer=True)
        if leds is not None:
            check("Chase", "leds", leds, ge=0, le=255, integer=True)
        require_field(source, "bins", who=f"{type(self).__name__} {name!r}")
        self.source = source
        self.speed = speed
        self.min_pixels = min_pixels
        self.leds = leds

    def act(self, state: State) -> Action | None:
        bins = pink_bins(state, self.source)
        if bins is None or sum(bins) < self.min_pixels:
            return None
        # Centre first, then inner, then outer: max() keeps the first of equal counts.
        order = (2, 1, 3, 0, 4)
        best = max(order, key=lambda i: bins[i])
        return Action(speed=self.speed, turn=BIN_TURNS[best], leds=self.leds)


class Flee(Behavior):
    """Back away from pink that is too close: speed 0 at ``start_pixels`` pink pixels in
    total, more negative with the count (one speed unit per pixel) down to ``min_speed``;
    turn 0.

    With chase's +40 the sum is 0 at 140 pixels (the comfortable distance), +20 at 120 and
    −40 (backing away) from 180 on. Below ``start_pixels`` flee abstains.
    """

    def __init__(
        self,
        *,
        name: str = "flee",
        source: str = CAMERA_SOURCE,
        start_pixels: Pixels = 100,
        speed_per_pixel: Annotated[float, msgspec.Meta(ge=0)] = 1.0,
        min_speed: Annotated[float, msgspec.Meta(ge=-100, le=0)] = -80.0,
    ) -> None:
        super().__init__(name=name)
        check("Flee", "start_pixels", start_pixels, ge=0, integer=True)
        check("Flee", "speed_per_pixel", speed_per_pixel, ge=0)
        check("Flee", "min_speed", min_speed, ge=-100, le=0)
        require_field(source, "bins", who=f"{type(self).__name__} {name!r}")
        self.source = source
        self.start_pixels = start_pixels
        self.speed_per_pixel = speed_per_pixel
        self.min_speed = min_speed

    def act(self, state: State) -> Action | None:
        bins = pink_bins(state, self.source)
        if bins is None:
            return None
        count = sum(bins)
        if count < self.start_pixels:
            return None
        speed = max(self.min_speed, -(count - self.start_pixels) * self.speed_per_pixel)
        return Action(speed=speed, turn=0.0)


class Search(Behavior):
    """Look for the ball when no pink is seen: speed +10, turn ±80.

    On becoming active it keeps turning the way the robot was turning (the sign of the
    previous action's turn, i.e. toward where the ball was last seen). If there was no turn
    it sits still (speed 0, turn 0). A counter of ``period_s`` (robot clock) starts when it
    becomes active; each time it elapses a random direction is drawn from ``rng``. Any pink
    deactivates it and the counter restarts on the next activation. ``leds``, when given,
    is what the LEDs show while it searches (``0``: all off).
    """

    def __init__(
        self,
        *,
        name: str = "search",
        source: str = CAMERA_SOURCE,
        speed: Command = 10.0,
        turn: Command = 80.0,
        period_s: Annotated[float, msgspec.Meta(gt=0)] = 4.0,
        leds: LedMask | None = None,
        rng: random.Random | None = None,
    ) -> None:
        super().__init__(name=name)
        check("Search", "speed", speed, ge=-100, le=100)
        if leds is not None:
            check("Search", "leds", leds, ge=0, le=255, integer=True)
        self.leds = leds
        check("Search", "turn", turn, ge=-100, le=100)
        check("Search", "period_s", period_s, gt=0)
        require_field(source, "bins", who=f"{type(self).__name__} {name!r}")
        self.source = source
        self.speed = speed
        self.turn = turn
        self.period_ns = int(period_s * 1e9)
        self.rng = rng if rng is not None else random.Random()
        self.direction = 0
        self.next_pick_ns: int | None = None

    def reset(self) -> None:
        self.direction = 0
        self.next_pick_ns = None

    def act(self, state: State) -> Action | None:
        bins = pink_bins(state, self.source)
        if bins is None:
            return None
        if sum(bins) > 0:
            self.next_pick_ns = None
            return None
        now = state.now_ns
        if self.next_pick_ns is None:
            previous = state.previous_action
            turn = previous.turn if previous is not None and previous.turn else 0.0
            self.direction = (turn > 0) - (turn < 0)
            self.next_pick_ns = now + self.period_ns
        elif now >= self.next_pick_ns:
            self.direction = self.rng.choice((-1, 1))
            self.next_pick_ns = now + self.period_ns
        if self.direction == 0:
            return Action(speed=0.0, turn=0.0, leds=self.leds)
        return Action(speed=self.speed, turn=self.turn * self.direction, leds=self.leds)


def seek_pink_ball(
    *,
    source: str = CAMERA_SOURCE,
    search_period_s: float = 4.0,
    rng: random.Random | None = None,
    name: str = "seek_pink_ball",
) -> Composite:
    """The thesis's composite: search at priority 2; chase and flee share priority 1 and are
    summed by :class:`~ubf_async.core.arbiters.PriorityMerge`.

    Search only acts without pink and chase/flee only with it, so the two priority levels
    never compete in practice; search sits above so that it supersedes them, as in the
    thesis's figure 3.7.
    """
    return Composite(
        name=name,
        arbiter=PriorityMerge(),
        children=[
            Child(Search(source=source, period_s=search_period_s, rng=rng), priority=2),
            Child(Chase(source=source), priority=1),
            Child(Flee(source=source), priority=1),
        ],
    )
