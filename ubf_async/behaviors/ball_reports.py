"""Behaviours that only make sense in a fleet: tell the others where the ball is, and go there.

* ``report_ball`` — while the robot sees pink, estimate where the ball is and say so over the
  radio (the action's ``message``), at most every ``period_s``: ``"ball X Y"``, metres, in
  the frame of the robot's odometry. A fleet's world starts every robot's odometry at its
  start pose in the world (``docs/fleet.md``), so the fleet shares that frame. The estimate:
  distance from the pink count (the ball has a fixed size: ``ref_pixels`` pink pixels at
  ``ref_distance_m``, the count falling with the square of the distance — §3.4.2), bearing
  from the counts of the five bins (their centres at +14°, +7°, 0°, −7°, −14°).
* ``go_to_report`` — once a report has been heard (``radio/<name>``), turn toward the reported
  position and drive there; abstain while pink is seen (chase and flee take over), when within
  ``arrive_m`` of it, and ``remember_s`` after the last report.

Both are pure: they read the state and return an action, so they are tested without a bus.
"""

from __future__ import annotations

import math
from typing import Annotated

import msgspec

from ubf_async.behaviors.params import Command, Pixels, check
from ubf_async.behaviors.pink_ball import CAMERA_SOURCE, pink_bins
from ubf_async.core.action import Action
from ubf_async.core.behavior import Behavior
from ubf_async.core.state import State
from ubf_async.wire.topics import require_field

__all__ = ["BIN_BEARINGS_DEG", "ODOMETRY_SOURCE", "RADIO_SOURCE", "REPORT_PREFIX", "GoToReport",
           "ReportBall", "format_report", "parse_report", "wrap_deg"]

ODOMETRY_SOURCE = "odometry/wheels"
RADIO_SOURCE = "radio/link"
BIN_BEARINGS_DEG: tuple[float, ...] = (14.0, 7.0, 0.0, -7.0, -14.0)
"""The bins' centres, image order (left to right), positive to the robot's left."""
REPORT_PREFIX = "ball"


def format_report(x_m: float, y_m: float) -> str:
    return f"{REPORT_PREFIX} {x_m:.2f} {y_m:.2f}"


def parse_report(text: str) -> tuple[float, float] | None:
    """``(x, y)`` of a ``"ball X Y"`` message, ``None`` for any other text."""
    parts = text.split()
    if len(parts) != 3 or parts[0] != REPORT_PREFIX:
        return None
    try:
        x, y = float(parts[1]), float(parts[2])
    except ValueError:
        return None
    return (x, y) if math.isfinite(x) and math.isfinite(y) and max(abs(x), abs(y)) < 1e4 \
        else None


def wrap_deg(angle: float) -> float:
    return (angle + 180.0) % 360.0 - 180.0


class ReportBall(Behavior):
    """Say where the ball is over the radio while it is seen (module docstring)."""

    def __init__(
        self,
        *,
        name: str = "report_ball",
        camera: str = CAMERA_SOURCE,
        odometry: str = ODOMETRY_SOURCE,
        min_pixels: Pixels = 5,
        ref_pixels: Annotated[int, msgspec.Meta(gt=0)] = 140,
        ref_distance_m: Annotated[float, msgspec.Meta(gt=0)] = 0.45,
        period_s: Annotated[float, msgspec.Meta(gt=0)] = 1.0,
    ) -> None:
        super().__init__(name=name)
        check("ReportBall", "min_pixels", min_pixels, ge=1, integer=True)
        who = f"{type(self).__name__} {name!r}"
        require_field(camera, "bins", who=who)
        require_field(odometry, "x_m", who=who)
        self.camera = camera
        self.odometry = odometry
        self.min_pixels = min_pixels
        self.ref_pixels = ref_pixels
        self.ref_distance_m = ref_distance_m
        self.period_ns = round(period_s * 1e9)
        self.last_report_ns: int | None = None

    def reset(self) -> None:
        self.last_report_ns = None

    def estimate(self, state: State) -> tuple[float, float] | None:
        """Where the ball is in the odometry frame, or ``None`` if not seen."""
        bins = pink_bins(state, self.camera)
        x = state.value(self.odometry, "x_m")
        y = state.value(self.odometry, "y_m")
        heading = state.value(self.odometry, "heading_rad")
        if bins is None or x is None or y is None or heading is None:
            return None
        total = sum(bins)
        if total < self.min_pixels:
            return None
        distance = self.ref_distance_m * math.sqrt(self.ref_pixels / total)
        bearing = math.radians(sum(b * c for b, c in zip(BIN_BEARINGS_DEG, bins, strict=True))
                               / total)
        return (x + distance * math.cos(heading + bearing),
                y + distance * math.sin(heading + bearing))

    def act(self, state: State) -> Action | None:
        if self.last_report_ns is not None and state.now_ns - self.last_report_ns \
                < self.period_ns:
            return None
        where = self.estimate(state)
        if where is None:
            return None
        self.last_report_ns = state.now_ns
        return Action(message=format_report(*where))


class GoToReport(Behavior):
    """Head for the position another robot reported (module docstring)."""

    def __init__(
        self,
        *,
        name: str = "go_to_report",
        radio: str = RADIO_SOURCE,
        odometry: str = ODOMETRY_SOURCE,
        camera: str = CAMERA_SOURCE,
        speed: Command = 40.0,
        turn: Command = 60.0,
        aligned_deg: Annotated[float, msgspec.Meta(gt=0, le=180)] = 20.0,
        arrive_m: Annotated[float, msgspec.Meta(gt=0)] = 0.6,
        remember_s: Annotated[float, msgspec.Meta(gt=0)] = 30.0,
    ) -> None:
        super().__init__(name=name)
        check("GoToReport", "speed", speed, ge=-100, le=100)
        check("GoToReport", "turn", turn, ge=0, le=100)
        who = f"{type(self).__name__} {name!r}"
        require_field(radio, "text", who=who)
        require_field(odometry, "x_m", who=who)
        require_field(camera, "bins", who=who)
        self.radio = radio
        self.odometry = odometry
        self.camera = camera
        self.speed = speed
        self.turn = turn
        self.aligned_deg = aligned_deg
        self.arrive_m = arrive_m
        self.remember_ns = round(remember_s * 1e9)
        self.target: tuple[float, float] | None = None
        self.heard_ns: int | None = None

    def reset(self) -> None:
        self.target = None
        self.heard_ns = None

    def act(self, state: State) -> Action | None:
        text = state.value(self.radio, "text")
        report = parse_report(text) if isinstance(text, str) else None
        if report is not None:
            self.target, self.heard_ns = report, state.now_ns
        if self.target is None or self.heard_ns is None \
                or state.now_ns - self.heard_ns > self.remember_ns:
            return None
        bins = pink_bins(state, self.camera)
        if bins is not None and sum(bins) > 0:
            return None  # it sees pink itself: chase and flee know better
        x = state.value(self.odometry, "x_m")
        y = state.value(self.odometry, "y_m")
        heading = state.value(self.odometry, "heading_rad")
        if x is None or y is None or heading is None:
            return None
        dx, dy = self.target[0] - x, self.target[1] - y
        if math.hypot(dx, dy) <= self.arrive_m:
            return None
        error = wrap_deg(math.degrees(math.atan2(dy, dx) - heading))
        if abs(error) <= self.aligned_deg:
            return Action(speed=self.speed, turn=max(-self.turn, min(self.turn, 2.0 * error)))
        return Action(speed=0.0, turn=math.copysign(self.turn, error))
